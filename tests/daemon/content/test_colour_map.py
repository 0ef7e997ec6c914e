"""Colour to level against a characteristic: pictures on the display's axis come back on
it, colours off it take the nearest reachable level, and the two other maps are what they
say; the daemon's colours come from the reference viewpoint of the run's report."""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

from grassd.calib.colour_spaces import lab_to_srgb
from grassd.calib.ogcd import delta_E
from grassd.daemon.content.colour_map import (
    DisplayColours,
    levels_for_picture,
    srgb8_to_lab,
)
from grassd.daemon.content.feature import colours_from_report

LENGTHS = np.linspace(0.0, 20.0, 11)


def _lab(lengths: np.ndarray) -> np.ndarray:
    """A yellow-to-green pixel: lightness falls, a* goes green faster than b* (mm -> Lab)."""
    s = 1.0 / (1.0 + np.exp(-(lengths - 10.0) / 3.0))  # an S-shaped characteristic
    return np.stack([62.0 - 18.0 * s, -4.0 - 32.0 * s, 48.0 - 14.0 * s], -1)


@pytest.fixture
def colours() -> DisplayColours:
    table_mm = 20.0 * (np.arange(256) / 255.0) ** 0.8  # a table that is not linear
    return DisplayColours.from_curve(table_mm, LENGTHS, _lab(LENGTHS), "test")


def test_level_colours_follow_the_table(colours):
    assert colours.level_lab.shape == (256, 3)
    np.testing.assert_allclose(colours.level_lab[0], _lab(np.array([0.0]))[0])
    np.testing.assert_allclose(colours.level_lab[255], _lab(np.array([20.0]))[0])


def test_colours_on_the_axis_map_back_onto_it(colours):
    levels = np.arange(0, 256, 5)
    rgb = np.rint(lab_to_srgb(colours.level_lab[levels]) * 255).astype(np.uint8)
    pic = rgb.reshape(1, -1, 3)
    got = levels_for_picture(pic, "nearest_de00", colours)[0]
    want_lab = srgb8_to_lab(rgb)
    shown = colours.level_lab[got]
    de = delta_E(shown, want_lab)
    print(f"on-axis: dE00 of shown vs picture max {de.max():.2f}, median {np.median(de):.2f}; "
          f"level error max {np.abs(got.astype(int) - levels).max()}")
    assert de.max() < 1.0  # 8-bit sRGB rounding of the axis' own colours
    assert np.abs(got.astype(int) - levels).max() <= 6


def test_colours_off_the_axis_take_the_nearest_reachable_level(colours):
    rng = np.random.default_rng(52)
    pic = rng.integers(0, 256, (12, 20, 3), dtype=np.uint8)
    got = levels_for_picture(pic, "nearest_de00", colours)
    lab = srgb8_to_lab(pic.reshape(-1, 3))
    for i, level in enumerate(got.ravel()):  # every level, the picture's colour against all
        de = delta_E(np.repeat(lab[i:i + 1], 256, 0), colours.level_lab)
        assert de[level] == pytest.approx(de.min(), abs=1e-9)
    assert len(np.unique(got)) > 5


def test_lightness_normalisation_stretches_lightness_only(colours):
    pic = np.array([[[0, 0, 0], [255, 255, 255], [120, 160, 40]]], np.uint8)
    got = levels_for_picture(pic, "nearest_de00", colours, "lightness")[0]
    lab = srgb8_to_lab(pic[0])
    lo, hi = colours.level_lab[:, 0].min(), colours.level_lab[:, 0].max()
    lab[:, 0] = lo + (hi - lo) * lab[:, 0] / 100.0  # 0..100 onto the display's L* range
    for i, level in enumerate(got):
        de = delta_E(np.repeat(lab[i:i + 1], 256, 0), colours.level_lab)
        assert de[level] == pytest.approx(de.min(), abs=1e-9)
    assert not np.array_equal(got, levels_for_picture(pic, "nearest_de00", colours)[0])


def test_luminance_is_pillows_and_green_is_the_channel():
    rng = np.random.default_rng(7)
    pic = rng.integers(0, 256, (9, 13, 3), dtype=np.uint8)
    want = np.asarray(Image.fromarray(pic, "RGB").convert("L"))
    np.testing.assert_array_equal(levels_for_picture(pic, "luminance"), want)
    np.testing.assert_array_equal(levels_for_picture(pic, "nearest_de00", None), want)
    np.testing.assert_array_equal(levels_for_picture(pic, "green"), pic[..., 1])
    with pytest.raises(ValueError, match="map must be"):
        levels_for_picture(pic, "red")


def test_report_colours_from_the_reference_viewpoint():
    table_um = np.rint(np.linspace(0, 20000, 256)).astype(int).tolist()
    far = {"h_cm": 160.0, "d_m": 2.0, "theta_deg": 30.0, "lengths_mm": LENGTHS.tolist(),
           "lab_d50": (_lab(LENGTHS) + 5).tolist()}
    ref = {"h_cm": 170.0, "d_m": 2.0, "theta_deg": 0.0, "lengths_mm": LENGTHS.tolist(),
           "lab_d50": _lab(LENGTHS).tolist()}
    c = colours_from_report({"run_id": 3, "viewpoints": [far, ref]}, table_um)
    np.testing.assert_allclose(c.level_lab[255], _lab(np.array([20.0]))[0])
    assert "(170, 2, 0)" in c.source
    assert colours_from_report({"viewpoints": [{"h_cm": 170.0}]}, table_um) is None
    assert colours_from_report({"table_um": table_um}, table_um) is None


def test_mapping_never_waits_on_the_players_thread(colours):
    """An animation of 4096 distinct colours (about 0.6 s of CIEDE2000): the first frames
    come at once (luminance), the nearest predicted colours once mapped in the background."""
    import time

    from grassd.daemon.content.mapping import MappedAnimation
    from grassd.daemon.content.pictures import Animation

    rng = np.random.default_rng(3)
    frames = rng.integers(0, 256, (4, 32, 32, 3), dtype=np.uint8)
    m = MappedAnimation(Animation(frames, np.full(4, 0.1), "noise"), "nearest_de00")
    t0 = time.perf_counter()
    first = m.levels(colours)
    took = time.perf_counter() - t0
    np.testing.assert_array_equal(first, levels_for_picture(frames, "luminance").reshape(4, -1))
    assert took < 0.1, took
    assert m.wait(colours, 30)
    np.testing.assert_array_equal(m.levels(colours), levels_for_picture(
        frames, "nearest_de00", colours).reshape(4, -1))
    assert m.levels(colours) is m.levels(colours)  # mapped once for these colours
