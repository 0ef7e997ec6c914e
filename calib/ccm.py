"""Colour-correction matrix: map virtual (rendered) checker colours onto real (captured) ones.

The paper fits a plain 3x3 matrix M by multivariate least squares so that, for the 24 patches
of a colour checker in ProPhoto linear RGB, ``real ~= M . virtual``. Beside it we offer the
root-polynomial correction of Finlayson, Mackiewicz & Hurlbert (2015), "Color Correction Using
Root-Polynomial Regression", IEEE TIP 24(5), through colour-science's
``matrix_colour_correction(method="Finlayson 2015")``; being homogeneous of degree one it is, like
the 3x3, independent of exposure. Every fit reports its per-patch, mean and maximum CIEDE2000
residual (CIELAB with the D50 ProPhoto white), so both can be compared on the same patches.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from grassd.calib.array_checks import as_float_array, same_shape
from grassd.calib.colour_spaces import prophoto_to_lab
from grassd.calib.errors import ShapeError, UnknownMethodError


@dataclass(frozen=True, eq=False)
class ColourCorrection:
    """A fitted colour correction and its residuals on the patches it was fitted to.

    Attributes:
        method: "3x3" (the paper's matrix) or "root-polynomial" (Finlayson 2015).
        matrix: (3, 3) for "3x3"; (3, terms) for "root-polynomial".
        degree: root-polynomial degree (1 for "3x3").
        residual_de00: (N,) CIEDE2000 between corrected virtual and real patches.
        mean_de00, max_de00: mean and maximum of ``residual_de00``.
    """

    method: str
    matrix: NDArray[np.float64]
    degree: int
    residual_de00: NDArray[np.float64]
    mean_de00: float
    max_de00: float

    def apply(self, rgb: ArrayLike) -> NDArray[np.float64]:
        """Correct ProPhoto linear RGB (..., 3) from the virtual to the real camera."""
        arr = as_float_array(rgb, "rgb", last_dim=3)
        return _APPLY[self.method](arr, self.matrix, self.degree)


def residual_de00(predicted: ArrayLike, real: ArrayLike) -> NDArray[np.float64]:
    """Per-patch CIEDE2000 between two ProPhoto linear RGB arrays (N, 3), via D50 CIELAB."""
    import colour  # on first use: see grassd.calib.colour_spaces

    return colour.delta_E(prophoto_to_lab(predicted), prophoto_to_lab(real), method="CIE 2000")


def _fit_3x3(virtual: NDArray, real: NDArray, degree: int) -> NDArray[np.float64]:
    # real_i = M virtual_i  <=>  real = virtual @ M.T ; least squares column by column.
    m_t, *_ = np.linalg.lstsq(virtual, real, rcond=None)
    return m_t.T


def _apply_3x3(rgb: NDArray, matrix: NDArray, degree: int) -> NDArray[np.float64]:
    return rgb @ matrix.T


def _fit_root_poly(virtual: NDArray, real: NDArray, degree: int) -> NDArray[np.float64]:
    import colour  # on first use: see grassd.calib.colour_spaces

    return np.asarray(
        colour.characterisation.matrix_colour_correction(
            virtual, real, method="Finlayson 2015", degree=degree, root_polynomial_expansion=True
        ),
        dtype=np.float64,
    )


def _apply_root_poly(rgb: NDArray, matrix: NDArray, degree: int) -> NDArray[np.float64]:
    import colour  # on first use: see grassd.calib.colour_spaces

    return np.asarray(
        colour.characterisation.apply_matrix_colour_correction_Finlayson2015(
            rgb, matrix, degree=degree, root_polynomial_expansion=True
        ),
        dtype=np.float64,
    )


#: Method name -> fitting function (virtual (N,3), real (N,3), degree) -> matrix.
CCM_METHODS: dict[str, Callable[[NDArray, NDArray, int], NDArray[np.float64]]] = {
    "3x3": _fit_3x3,
    "root-polynomial": _fit_root_poly,
}
_APPLY: dict[str, Callable[[NDArray, NDArray, int], NDArray[np.float64]]] = {
    "3x3": _apply_3x3,
    "root-polynomial": _apply_root_poly,
}


def fit_ccm(
    virtual: ArrayLike, real: ArrayLike, method: str = "3x3", *, degree: int = 2
) -> ColourCorrection:
    """Fit ``real ~= correction(virtual)`` over checker patches in ProPhoto linear RGB.

    Args:
        virtual: (N, 3) ProPhoto linear RGB of the rendered patches (N >= 3; 24 for a checker).
        real: (N, 3) ProPhoto linear RGB of the captured patches, same order.
        method: "3x3" (plain least-squares matrix, the paper's) or "root-polynomial".
        degree: root-polynomial degree (2 or 3); ignored for "3x3".

    Returns:
        The fit with its per-patch / mean / max CIEDE2000 residuals.

    >>> rgb = np.random.default_rng(0).uniform(0.05, 0.9, (24, 3))
    >>> M = np.array([[1.1, 0.05, 0.0], [0.02, 0.95, 0.03], [0.0, 0.1, 0.9]])
    >>> fit = fit_ccm(rgb, rgb @ M.T)
    >>> bool(np.allclose(fit.matrix, M)), fit.max_de00 < 1e-9
    (True, True)
    """
    if method not in CCM_METHODS:
        raise UnknownMethodError(
            f"unknown colour-correction method {method!r}; use one of {', '.join(CCM_METHODS)}"
        )
    v = as_float_array(virtual, "virtual", last_dim=3, ndim=2, non_negative=True)
    r = as_float_array(real, "real", last_dim=3, ndim=2, non_negative=True)
    same_shape(v, r, "virtual", "real")
    deg = 1 if method == "3x3" else int(degree)
    n_terms = {1: 3, 2: 6, 3: 13, 4: 22}.get(deg) if method != "3x3" else 3
    if n_terms is None:
        raise UnknownMethodError(f"root-polynomial degree must be 1..4; got {degree}")
    if v.shape[0] < n_terms:
        raise ShapeError(
            f"a {method} fit of degree {deg} needs at least {n_terms} patches; got {v.shape[0]}"
        )
    if np.linalg.matrix_rank(v) < 3:
        raise ShapeError(
            "the virtual patches do not span three colour dimensions (all grey or collinear); "
            "fit on a chart with chromatic patches"
        )
    matrix = CCM_METHODS[method](v, r, deg)
    predicted = np.clip(_APPLY[method](v, matrix, deg), 0.0, None)
    res = residual_de00(predicted, r)
    return ColourCorrection(
        method=method,
        matrix=matrix,
        degree=deg,
        residual_de00=res,
        mean_de00=float(res.mean()),
        max_de00=float(res.max()),
    )


def compare_ccm_methods(
    virtual: ArrayLike, real: ArrayLike, *, degree: int = 2
) -> dict[str, ColourCorrection]:
    """Fit both the paper's 3x3 and the root-polynomial correction; {method: fit}."""
    return {m: fit_ccm(virtual, real, m, degree=degree) for m in CCM_METHODS}
