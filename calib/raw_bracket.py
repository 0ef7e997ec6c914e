"""Develop a bracket of RAW shots (DNG) to linear Rec.709 for ``hdr_merge.merge_linear``.

Each shot is developed by LibRaw (:func:`grassd.calib.raw.develop_raw`: camera white balance,
gamma 1, no auto-brightening, 16 bit) at half size, one texel per 2 x 2 Bayer block: no
demosaicing, whose interpolation would smear a sun of a few photosites into its neighbours
and lose its colour (a light probe needs radiance more than resolution). It is converted from
ProPhoto to linear Rec.709. A RAW is linear up to the sensor's saturation, so no response is
recovered; what matters is to know where it saturated: a developed value near 1 is not enough
(white-balance multipliers move the clip point per channel), so every texel whose Bayer block
holds a photosite at or above :data:`SATURATION` x (white level - black) + black is set to 1
in all channels, which ``merge_linear`` treats as clipped.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from grassd.calib.colour_spaces import prophoto_to_rec709
from grassd.calib.errors import RawReadError
from grassd.calib.raw import develop_raw, open_raw

#: Fraction of the raw range above which a photosite counts as saturated.
SATURATION: float = 0.98


def saturated_texels(path: str | Path) -> NDArray[np.bool_]:
    """(H / 2, W / 2) bool: the 2 x 2 Bayer blocks holding a saturated photosite (one per
    texel of a half-size development). Compared in the raw integers (a photosite is saturated
    at or above the integer ceiling of the threshold), block by block, without a float copy of
    the sensor (a 27 Mpx THETA Z1 frame would take 210 MB)."""
    import rawpy

    raw_file = open_raw(path)  # its declared size checked before unpacking
    try:
        with raw_file as raw:
            black = float(np.mean(raw.black_level_per_channel))
            limit = math.ceil(black + SATURATION * (float(raw.white_level) - black))
            data = raw.raw_image_visible
            h2, w2 = data.shape[0] - data.shape[0] % 2, data.shape[1] - data.shape[1] % 2
            d = data[:h2, :w2]
            return ((d[0::2, 0::2] >= limit) | (d[0::2, 1::2] >= limit)
                    | (d[1::2, 0::2] >= limit) | (d[1::2, 1::2] >= limit))
    except (rawpy.LibRawError, OSError, ValueError) as exc:
        raise RawReadError(f"{path} is not a RAW file LibRaw can open ({exc})") from exc


def develop_bracket(paths: Sequence[str | Path]) -> list[NDArray[np.float32]]:
    """Develop RAW shots to (H / 2, W / 2, 3) float32 linear Rec.709 (1 = full scale),
    saturated texels set to 1 (module docstring)."""
    out = []
    for p in paths:
        dev = develop_raw(p, half_size=True)
        rgb = prophoto_to_rec709(dev.rgb).astype(np.float32)
        sat = saturated_texels(p)
        if sat.shape == rgb.shape[:2]:
            rgb[sat] = 1.0
        else:  # LibRaw cropped margins: judge by the developed values alone
            rgb[rgb.max(axis=2) >= SATURATION] = 1.0
        out.append(np.maximum(rgb, 0.0))
    return out
