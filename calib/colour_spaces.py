"""Colour-space conversions of the grassd pipeline, with every convention stated here once.

Conventions (the single source of truth for the whole package):

* **Normalisation**: all tristimulus values are relative, with **Y = 1 for a perfect white
  diffuser** (XYZ in [0, 1] for reflective colours); CIELAB L* = 100 at Y = 1.
* **Linear Rec.709** (a.k.a. scRGB / linear sRGB, what the renderer produces): ITU-R BT.709
  primaries, white **D65** (x, y) = (0.3127, 0.3290); scene-linear (no transfer function).
* **ProPhoto linear RGB** (ROMM RGB primaries, what LibRaw's ``output_color=ProPhoto`` gives with
  gamma (1, 1)): white **D50** (x, y) = (0.3457, 0.3585), the ICC PCS white, XYZ = (0.9642, 1,
  0.8249).
* **Chromatic adaptation** between D65 and D50 is **Bradford** (Lam 1985, as used by LibRaw and
  ICC). colour-science 0.4 defaults to CAT02, which differs by up to ~0.6 dE00 on a checker, so
  the adaptation is always passed explicitly.
* **CIELAB** uses the **ProPhoto (D50) white**. colour-science's ``XYZ_to_Lab`` defaults to D65,
  so the white is always passed explicitly.

The matrices are colour-science's (its colourspace definitions and Bradford transform), written
out here to the last bit and exposed read-only; tests/calib/test_colour_space_constants.py checks
them against colour-science. ``import colour`` loads its plotting too (matplotlib, pandas: about
100 MiB and seconds), so it happens only in the functions that call colour-science (CIELAB
conversions): the daemon idles and the light commands start without it.
References: ITU-R BT.709-6; ANSI/I3A IT10.7666 (ROMM RGB); CIE 15:2018 (CIELAB).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from grassd.calib.array_checks import as_float_array
from grassd.calib.errors import UnknownMethodError

#: Chromatic adaptation transform used everywhere (never colour-science's CAT02 default).
ADAPTATION: str = "Bradford"

#: colour-science's ``RGB_COLOURSPACES["ITU-R BT.709"].matrix_RGB_to_XYZ``
_REC709_RGB_TO_XYZ = (
    (0.41239079926595934, 0.35758433938387796, 0.1804807884018343),
    (0.2126390058715103, 0.7151686787677559, 0.07219231536073371),
    (0.019330818715591825, 0.11919477979462595, 0.9505321522496606),
)
#: colour-science's ``RGB_COLOURSPACES["ProPhoto RGB"].matrix_RGB_to_XYZ``
_PROPHOTO_RGB_TO_XYZ = ((0.7977, 0.1352, 0.0313), (0.288, 0.7119, 0.0001), (0.0, 0.0, 0.8249))
#: colour-science's ``adaptation.matrix_chromatic_adaptation_VonKries(WHITE_D65_XYZ,
#: WHITE_D50_XYZ, transform="Bradford")``
_BRADFORD_D65_TO_D50 = (
    (1.0478860032225505, 0.022918765174779504, -0.050216095311733044),
    (0.02958178249800338, 0.9904835184905487, -0.01707870770448269),
    (-0.009251880839208845, 0.015072607487031322, 0.7516781336176034),
)


def _frozen(m: ArrayLike) -> NDArray[np.float64]:
    a = np.array(m, dtype=np.float64)
    a.setflags(write=False)
    return a


def _XYZ_to_xy(xyz: NDArray[np.float64]) -> NDArray[np.float64]:
    return _frozen(xyz[:2] / xyz.sum())


#: XYZ of the D65 white (Y = 1): Rec.709 RGB (1, 1, 1); xy = (0.3127, 0.3290).
WHITE_D65_XYZ: NDArray[np.float64] = _frozen(np.asarray(_REC709_RGB_TO_XYZ).sum(axis=1))
#: XYZ of the D50 ICC white (Y = 1): ProPhoto RGB (1, 1, 1) = (0.9642, 1, 0.8249); the CIELAB white.
WHITE_D50_XYZ: NDArray[np.float64] = _frozen(np.asarray(_PROPHOTO_RGB_TO_XYZ).sum(axis=1))
#: CIE 1931 2-degree chromaticity of the D65 white.
WHITE_D65_XY: NDArray[np.float64] = _XYZ_to_xy(WHITE_D65_XYZ)
#: CIE 1931 2-degree chromaticity of the D50 white, (0.34570, 0.35854).
WHITE_D50_XY: NDArray[np.float64] = _XYZ_to_xy(WHITE_D50_XYZ)

#: Linear Rec.709 -> XYZ (D65-relative).
M_REC709_TO_XYZ = _frozen(_REC709_RGB_TO_XYZ)
#: XYZ (D65-relative) -> linear Rec.709.
M_XYZ_TO_REC709 = _frozen(np.linalg.inv(M_REC709_TO_XYZ))
#: ProPhoto linear RGB -> XYZ (D50-relative).
M_PROPHOTO_TO_XYZ = _frozen(_PROPHOTO_RGB_TO_XYZ)
#: XYZ (D50-relative) -> ProPhoto linear RGB.
M_XYZ_TO_PROPHOTO = _frozen(np.linalg.inv(M_PROPHOTO_TO_XYZ))
#: Bradford adaptation of XYZ from D65 to D50.
M_CAT_D65_TO_D50 = _frozen(_BRADFORD_D65_TO_D50)
#: Bradford adaptation of XYZ from D50 to D65.
M_CAT_D50_TO_D65 = _frozen(np.linalg.inv(M_CAT_D65_TO_D50))
#: Linear Rec.709 (D65) -> ProPhoto linear (D50), Bradford; equals LibRaw's ``prophoto_rgb``.
M_REC709_TO_PROPHOTO = _frozen(M_XYZ_TO_PROPHOTO @ M_CAT_D65_TO_D50 @ M_REC709_TO_XYZ)
#: ProPhoto linear (D50) -> linear Rec.709 (D65), Bradford.
M_PROPHOTO_TO_REC709 = _frozen(np.linalg.inv(M_REC709_TO_PROPHOTO))

#: RGB working spaces accepted by the ``space=`` arguments of this package.
SPACES: tuple[str, ...] = ("prophoto", "rec709")


def _apply(matrix: NDArray[np.float64], values: ArrayLike, name: str) -> NDArray[np.float64]:
    arr = as_float_array(values, name, last_dim=3)
    return arr @ matrix.T


def rec709_to_xyz(rgb: ArrayLike) -> NDArray[np.float64]:
    """Linear Rec.709 RGB (..., 3) -> CIE XYZ relative to D65 (Y of white = 1)."""
    return _apply(M_REC709_TO_XYZ, rgb, "rgb")


def xyz_to_rec709(xyz: ArrayLike) -> NDArray[np.float64]:
    """CIE XYZ relative to D65 (..., 3) -> linear Rec.709 RGB."""
    return _apply(M_XYZ_TO_REC709, xyz, "xyz")


def xyz_d65_to_d50(xyz: ArrayLike) -> NDArray[np.float64]:
    """Bradford-adapt XYZ (..., 3) from the D65 white to the D50 white."""
    return _apply(M_CAT_D65_TO_D50, xyz, "xyz")


def xyz_d50_to_d65(xyz: ArrayLike) -> NDArray[np.float64]:
    """Bradford-adapt XYZ (..., 3) from the D50 white to the D65 white."""
    return _apply(M_CAT_D50_TO_D65, xyz, "xyz")


def prophoto_to_xyz(rgb: ArrayLike) -> NDArray[np.float64]:
    """ProPhoto linear RGB (..., 3) -> CIE XYZ relative to D50 (Y of white = 1)."""
    return _apply(M_PROPHOTO_TO_XYZ, rgb, "rgb")


def xyz_to_prophoto(xyz: ArrayLike) -> NDArray[np.float64]:
    """CIE XYZ relative to D50 (..., 3) -> ProPhoto linear RGB."""
    return _apply(M_XYZ_TO_PROPHOTO, xyz, "xyz")


def rec709_to_prophoto(rgb: ArrayLike) -> NDArray[np.float64]:
    """Linear Rec.709 (D65) RGB (..., 3) -> ProPhoto linear RGB (D50) via XYZ and Bradford.

    >>> np.round(rec709_to_prophoto([1.0, 1.0, 1.0]), 6).tolist()  # D65 white -> ProPhoto white
    [1.0, 1.0, 1.0]
    """
    return _apply(M_REC709_TO_PROPHOTO, rgb, "rgb")


def prophoto_to_rec709(rgb: ArrayLike) -> NDArray[np.float64]:
    """ProPhoto linear RGB (D50) (..., 3) -> linear Rec.709 RGB (D65) via XYZ and Bradford."""
    return _apply(M_PROPHOTO_TO_REC709, rgb, "rgb")


def to_prophoto(rgb: ArrayLike, space: str) -> NDArray[np.float64]:
    """Linear RGB (..., 3) in ``space`` ("prophoto" or "rec709") -> ProPhoto linear RGB."""
    return (
        rec709_to_prophoto(rgb)
        if space_key(space) == "rec709"
        else as_float_array(rgb, "rgb", last_dim=3)
    )


def space_key(space: str) -> str:
    """Canonical name ("rec709" or "prophoto") of an RGB space name (scRGB, BT.709, ROMM ...)."""
    key = str(space).lower().replace(".", "").replace("-", "").replace("_", "")
    if key in ("rec709", "bt709", "scrgb", "linearsrgb"):
        return "rec709"
    if key in ("prophoto", "romm"):
        return "prophoto"
    raise UnknownMethodError(f"unknown RGB space {space!r}; use one of {', '.join(SPACES)}")


def xyz_to_lab(xyz: ArrayLike) -> NDArray[np.float64]:
    """CIE XYZ relative to D50 (Y of white = 1) (..., 3) -> CIELAB with the D50 (ProPhoto) white.

    The white is passed explicitly to colour-science (whose default would be D65).

    >>> (np.round(xyz_to_lab(WHITE_D50_XYZ), 10) + 0.0).tolist()
    [100.0, 0.0, 0.0]
    """
    import colour  # here: module docstring

    arr = as_float_array(xyz, "xyz", last_dim=3)
    return np.asarray(colour.XYZ_to_Lab(arr, illuminant=WHITE_D50_XY), dtype=np.float64)


def lab_to_xyz(lab: ArrayLike) -> NDArray[np.float64]:
    """CIELAB with the D50 white (..., 3) -> CIE XYZ relative to D50 (Y of white = 1)."""
    import colour

    arr = as_float_array(lab, "lab", last_dim=3)
    return np.asarray(colour.Lab_to_XYZ(arr, illuminant=WHITE_D50_XY), dtype=np.float64)


def prophoto_to_lab(rgb: ArrayLike) -> NDArray[np.float64]:
    """ProPhoto linear RGB (..., 3) -> CIELAB (D50 white)."""
    return xyz_to_lab(prophoto_to_xyz(rgb))


def lab_to_prophoto(lab: ArrayLike) -> NDArray[np.float64]:
    """CIELAB (D50 white) (..., 3) -> ProPhoto linear RGB."""
    return xyz_to_prophoto(lab_to_xyz(lab))


def luminance(rgb: ArrayLike, space: str = "prophoto") -> NDArray[np.float64]:
    """Relative luminance Y (Y of white = 1) of linear RGB (..., 3) in ``space``."""
    arr = as_float_array(rgb, "rgb", last_dim=3)
    row = M_REC709_TO_XYZ[1] if space_key(space) == "rec709" else M_PROPHOTO_TO_XYZ[1]
    return arr @ row


def srgb_encode(linear: ArrayLike) -> NDArray[np.float64]:
    """IEC 61966-2-1 (sRGB) encoding of linear Rec.709 values, clipped to 0..1 first; encoded
    values in 0..1 (for display).

    >>> srgb_encode([0.0, 0.18, 1.0, 2.0]).round(4).tolist()
    [0.0, 0.4614, 1.0, 1.0]
    """
    x = np.clip(np.asarray(linear, dtype=np.float64), 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)


def lab_to_srgb(lab: ArrayLike) -> NDArray[np.float64]:
    """Encoded sRGB (..., 3) in 0..1 of D50 CIELAB colours (Bradford to D65; for display,
    clipped to the gamut)."""
    return srgb_encode(prophoto_to_rec709(lab_to_prophoto(np.asarray(lab, dtype=np.float64))))
