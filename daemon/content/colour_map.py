"""A picture's colours onto the display's one colour axis: the level per pixel.

``map = "nearest_de00"`` (the default) asks the calibration: for every pixel, the level whose
predicted colour is nearest in CIEDE2000 to the picture's colour. The predicted colour of a
level is the simulated pixel's D50 CIELAB at the table's length for that level (the current
characteristic, at the reference viewpoint, under the current light), interpolated linearly
between the simulated lengths (:class:`DisplayColours`). The picture's colour is its sRGB
value decoded (IEC 61966-2-1) to linear Rec.709, then to D50 CIELAB through ProPhoto
(Bradford), as the calibration's colours are.

Normalisation (``normalise``): ``"none"`` reads the picture's sRGB white as the white the
simulation's colours are relative to (L* 100), so a picture drawn in the display's own
colours (the studio's view of the display, say) maps back onto those levels; ``"lightness"``
stretches the picture's L* from 0..100 onto the display's L* range (its darkest to its
lightest predicted colour), keeping a* and b*, so that a picture's black and white reach the
display's two ends.

``map = "luminance"``: the picture's luma (ITU-R BT.601 weights, Pillow's "L") as the level;
``"green"``: its green channel. Neither needs a calibration.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from grassd.calib.length_table import LEVELS

#: colours compared with all 256 levels at once (bounds the (chunk, 256, 3) temporaries)
_CHUNK = 4096
#: the reference viewpoint (h cm, d m, theta deg) whose colours content is mapped onto
REFERENCE_VIEWPOINT: tuple[float, float, float] = (170.0, 2.0, 0.0)


@dataclass(frozen=True, eq=False)
class DisplayColours:
    """``level_lab`` (256, 3): the D50 CIELAB the display is predicted to show at each level;
    ``source``: where it comes from (for status)."""

    level_lab: NDArray[np.float64]
    source: str

    @classmethod
    def from_curve(cls, table_mm: ArrayLike, lengths_mm: ArrayLike, lab: ArrayLike,
                   source: str) -> DisplayColours:
        """The colours of the levels of ``table_mm`` (256,) [mm] from a simulated curve:
        ``lab`` (n, 3) D50 CIELAB at ``lengths_mm`` (n,) [mm], linearly interpolated."""
        table = np.asarray(table_mm, np.float64)
        xs = np.asarray(lengths_mm, np.float64)
        ys = np.asarray(lab, np.float64)
        if table.shape != (LEVELS,) or ys.shape != (xs.size, 3) or xs.size < 2:
            raise ValueError(f"need a (256,) table and (n, 3) Lab at n >= 2 lengths; got "
                             f"{table.shape}, {ys.shape} at {xs.shape}")
        order = np.argsort(xs)
        xs, ys = xs[order], ys[order]
        out = np.stack([np.interp(table, xs, ys[:, k]) for k in range(3)], axis=-1)
        return cls(out, source)


def srgb8_to_lab(rgb8: ArrayLike) -> NDArray[np.float64]:
    """8-bit sRGB (..., 3) -> D50 CIELAB (..., 3) (decoded, Rec.709 -> ProPhoto -> Lab)."""
    from grassd.calib.colour_spaces import prophoto_to_lab, rec709_to_prophoto

    v = np.asarray(rgb8, np.float64) / 255.0
    linear = np.where(v <= 0.04045, v / 12.92, ((v + 0.055) / 1.055) ** 2.4)
    return prophoto_to_lab(rec709_to_prophoto(linear))


def nearest_levels(lab: NDArray[np.float64], level_lab: NDArray[np.float64]
                   ) -> NDArray[np.uint8]:
    """(N,) for each colour of ``lab`` (N, 3) the level whose ``level_lab`` (256, 3) colour
    is nearest in CIEDE2000 (the lowest such level on a tie)."""
    from grassd.calib.ogcd import delta_E

    out = np.empty(lab.shape[0], np.uint8)
    for a in range(0, lab.shape[0], _CHUNK):
        part = lab[a:a + _CHUNK]
        de = delta_E(part[:, None, :], level_lab[None, :, :], method="CIE 2000")
        out[a:a + _CHUNK] = np.argmin(de, axis=1)
    return out


def levels_for_picture(rgb8: ArrayLike, mode: str = "nearest_de00",
                       colours: DisplayColours | None = None,
                       normalise: str = "none") -> NDArray[np.uint8]:
    """The levels (...,) uint8 that show the 8-bit sRGB picture ``rgb8`` (..., 3) by
    ``mode`` ("nearest_de00", "luminance" or "green"; see the module docstring). Without
    ``colours`` (no calibration yet) "nearest_de00" falls back to "luminance"."""
    rgb = np.asarray(rgb8)
    if rgb.shape[-1:] != (3,):
        raise ValueError(f"an RGB picture has 3 channels last; got shape {rgb.shape}")
    rgb = rgb.astype(np.uint8, copy=False)
    if mode == "green":
        return rgb[..., 1].copy()
    if mode == "luminance" or (mode == "nearest_de00" and colours is None):
        r, g, b = (rgb[..., k].astype(np.uint32) for k in range(3))
        return ((r * 19595 + g * 38470 + b * 7471 + 0x8000) >> 16).astype(np.uint8)  # as "L"
    if mode != "nearest_de00":
        raise ValueError(f"map must be 'nearest_de00', 'luminance' or 'green', not {mode!r}")
    assert colours is not None
    flat = rgb.reshape(-1, 3)
    packed = (flat[:, 0].astype(np.uint32) << 16) | (flat[:, 1].astype(np.uint32) << 8) \
        | flat[:, 2]
    unique, inverse = np.unique(packed, return_inverse=True)
    ucol = np.stack([(unique >> 16) & 255, (unique >> 8) & 255, unique & 255], -1)
    lab = srgb8_to_lab(ucol)
    if normalise == "lightness":
        lo, hi = colours.level_lab[:, 0].min(), colours.level_lab[:, 0].max()
        lab = lab.copy()
        lab[:, 0] = lo + (hi - lo) * lab[:, 0] / 100.0
    elif normalise != "none":
        raise ValueError(f"normalise must be 'none' or 'lightness', not {normalise!r}")
    return nearest_levels(lab, colours.level_lab)[inverse.ravel()].reshape(rgb.shape[:-1])
