"""A RAW bracket shot marks as clipped exactly the texels (2 x 2 Bayer blocks) holding a
photosite at or above the saturation threshold, read from a real DNG by LibRaw."""

from __future__ import annotations

import numpy as np
import rawpy

from grassd.calib.dng import DngCamera, write_dng
from grassd.calib.raw_bracket import SATURATION, develop_bracket, saturated_texels


def test_saturated_blocks_are_the_ones_with_a_photosite_at_the_threshold(tmp_path):
    cam = DngCamera()
    span = cam.white_level - cam.black_level
    limit = cam.black_level + SATURATION * span
    rng = np.random.default_rng(4)
    raw = rng.integers(cam.black_level, int(limit) - 50, size=(64, 96)).astype(np.uint16)
    # single photosites on either side of the threshold, in each of the four CFA positions
    raw[10, 20] = cam.white_level                    # clipped
    raw[11, 31] = int(np.ceil(limit))               # just at the threshold: saturated
    raw[20, 41] = int(np.ceil(limit)) - 1           # just below: not saturated
    raw[31, 50] = int(np.ceil(limit)) + 3
    path = write_dng(tmp_path / "shot.dng", raw, cam)
    with rawpy.imread(str(path)) as r:  # what LibRaw reads back, compared in floating point
        seen = r.raw_image_visible.astype(np.float64)
        black, white = float(np.mean(r.black_level_per_channel)), float(r.white_level)
    h, w = seen.shape
    expected = (seen >= black + SATURATION * (white - black)).reshape(
        h // 2, 2, w // 2, 2).any(axis=(1, 3))
    sat = saturated_texels(path)
    assert sat.shape == (32, 48)
    np.testing.assert_array_equal(sat, expected)
    assert sat[5, 10] and sat[5, 15] and sat[15, 25] and not sat[10, 20] and sat.sum() == 3
    dev = develop_bracket([path])[0]
    assert dev.shape[:2] == sat.shape
    assert (dev[sat] == 1.0).all()
