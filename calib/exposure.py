"""Exposure normalisation: scale linear RGB so that an 18 % grey patch reads Y = 0.18.

The same function serves real captures (ProPhoto linear from :mod:`grassd.calib.raw`) and renders
(linear Rec.709 from the renderer): the caller hands the linear RGB of its grey reference, a real
18 % grey card in the photograph or the renderer's virtual grey card, and gets back the image
scaled by ``0.18 / Y(grey)``. With ``white_balance=True`` a diagonal (von Kries) gain in ProPhoto
linear RGB is applied as well, so that the grey reads neutral, i.e. R = G = B in ProPhoto, which is
the D50 white of CIELAB here. Normalisation conventions: :mod:`grassd.calib.colour_spaces`.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from grassd.calib.array_checks import as_float_array
from grassd.calib.colour_spaces import (
    M_PROPHOTO_TO_REC709,
    M_REC709_TO_PROPHOTO,
    luminance,
    space_key,
)
from grassd.calib.errors import ExposureError

#: Luminance factor of a photographic 18 % grey card (Y relative to a perfect white = 1).
GREY_CARD_Y: float = 0.18


def exposure_matrix(
    grey_rgb: ArrayLike,
    *,
    space: str = "prophoto",
    white_balance: bool = False,
    target_y: float = GREY_CARD_Y,
) -> NDArray[np.float64]:
    """3x3 matrix ``G`` (in ``space``) such that ``rgb @ G.T`` is exposure-normalised.

    Args:
        grey_rgb: linear RGB (3,) of the grey reference (any exposure), in ``space``.
        space: "prophoto" (captures) or "rec709" (renders).
        white_balance: also make the grey neutral with a diagonal gain in ProPhoto linear.
        target_y: luminance the grey must read after normalisation (0.18 for an 18 % card).

    Without white balance ``G`` is ``0.18 / Y(grey)`` times the identity. With it, ``G`` is
    ``target_y / g_P`` times the identity expressed in ``space``, where ``g_P`` is the grey
    converted to ProPhoto (for a neutral grey R = G = B and Y = R: the ProPhoto white has Y = 1).

    >>> G = exposure_matrix([0.09, 0.09, 0.09])
    >>> np.round(np.diag(G), 6).tolist()
    [2.0, 2.0, 2.0]
    """
    grey = as_float_array(grey_rgb, "grey_rgb", last_dim=3, ndim=1, non_negative=True)
    key = space_key(space)
    if not np.isfinite(target_y) or target_y <= 0:
        raise ExposureError(f"target_y must be a positive luminance; got {target_y}")
    y = float(luminance(grey, key))
    if y <= 1e-12:
        raise ExposureError(
            f"the grey reference {grey.tolist()} has luminance Y = {y:.3g}; it must be a lit grey "
            "patch (Y > 0): check its position and the exposure"
        )
    if not white_balance:
        return np.eye(3) * (target_y / y)
    grey_pp = grey @ M_REC709_TO_PROPHOTO.T if key == "rec709" else grey
    if (grey_pp <= 1e-12).any():
        raise ExposureError(
            f"the grey reference reads {grey_pp.tolist()} in ProPhoto linear; a channel <= 0 "
            "cannot be white-balanced: check the grey patch position and that it is not clipped"
        )
    gains = np.diag(target_y / grey_pp)
    if key == "rec709":
        return M_PROPHOTO_TO_REC709 @ gains @ M_REC709_TO_PROPHOTO
    return gains


def normalise_exposure(
    rgb: ArrayLike,
    grey_rgb: ArrayLike,
    *,
    space: str = "prophoto",
    white_balance: bool = False,
    target_y: float = GREY_CARD_Y,
) -> NDArray[np.float64]:
    """Scale linear RGB (..., 3) so that ``grey_rgb`` reads luminance Y = ``target_y`` (0.18).

    ``rgb`` and ``grey_rgb`` are linear (not gamma-encoded) and in the same ``space``
    ("prophoto" for captures, "rec709" for renders); the result is in that space too. See
    :func:`exposure_matrix` for the white-balance option.

    >>> out = normalise_exposure([[0.5, 0.5, 0.5]], [0.25, 0.25, 0.25])
    >>> np.round(out, 6).tolist()
    [[0.36, 0.36, 0.36]]
    """
    arr = as_float_array(rgb, "rgb", last_dim=3, non_negative=True)
    return (
        arr
        @ exposure_matrix(grey_rgb, space=space, white_balance=white_balance, target_y=target_y).T
    )
