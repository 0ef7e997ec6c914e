"""The studio's views computed with numpy: the contrast a designer has, the table judged live or
as the daemon's, a picture read as the display's levels, and the display drawn from the eye."""

from __future__ import annotations

import io

import numpy as np
import pytest
from conftest import png_bytes

from grassd.calib.characteristic import Characteristic, fit_characteristic
from grassd.daemon.studio import views


def _fit():
    x = np.linspace(0, 20, 11)
    return fit_characteristic(Characteristic(x, 25 * (x / 20) ** 2, np.full(11, 0.05)))


def test_contrast_counts_the_levels_a_viewer_tells_apart():
    c = views.contrast_view(24.3)
    assert c["distinct_levels"] == 25  # 0, 1, ..., 24 dE00
    assert c["step_de00"] == pytest.approx(24.3 / 255)
    assert c["min_visible_step_levels"] == 11  # ceil(1 / 0.0953)
    assert views.contrast_view(500.0)["distinct_levels"] == 256
    assert views.contrast_view(0.0)["distinct_levels"] == 1


def test_the_audience_warning_marks_places_that_lose_contrast():
    warn = views.audience_warning(np.array([20.0, 14.1, 13.9, 5.0]), 20.0, loss=0.3)
    assert warn.tolist() == [False, False, True, True]


def test_the_live_table_linearises_and_an_active_table_is_judged_against_the_curve():
    fit = _fit()
    live = views.table_view(fit, None)
    assert live["source"] == "live" and live["r2_after"] > 0.9999 > live["r2_before"]
    linear = np.rint(np.linspace(0, 20000, 256)).astype(np.uint16)  # length linear in level
    active = views.table_view(fit, linear)
    assert active["source"] == "active"
    assert active["r2_after"] == pytest.approx(live["r2_before"], abs=1e-4)
    assert active["max_level_error"] > 3 * live["max_level_error"]


def test_a_picture_becomes_the_displays_levels():
    rgb = np.zeros((40, 80, 3), np.uint8)
    rgb[:, 40:] = 255
    levels = views.picture_levels(png_bytes(rgb, "RGB"), 4, 8)
    assert levels.shape == (4, 8)
    assert levels[:, :4].max() == 0 and levels[:, 4:].min() == 255
    with pytest.raises(ValueError, match="not a picture"):
        views.picture_levels(b"\x89PNG\r\n\x1a\n broken", 4, 8)
    with pytest.raises(ValueError, match="at most 8 MiB"):
        views.picture_levels(b"\0" * (views.MAX_IMAGE_BYTES + 1), 4, 8)


def _decode(url: str) -> np.ndarray:
    import base64

    from PIL import Image

    assert url.startswith("data:image/png;base64,")
    return np.asarray(Image.open(io.BytesIO(base64.b64decode(url.split(",", 1)[1]))))


def test_the_display_view_draws_each_pixel_in_its_simulated_colour():
    lengths = np.array([0.0, 10.0, 20.0])
    lab = np.array([[70.0, 0.0, 50.0], [50.0, -20.0, 30.0], [30.0, -30.0, 20.0]])
    table = np.linspace(0, 20, 256)
    levels = np.zeros((4, 8), np.uint8)
    levels[:, 4:] = 255
    img = _decode(views.display_view(levels, table, lengths, lab, 33.5,
                                     np.array([0.0, -2.0, 1.7]), width=320))
    assert img.shape[1] == 320
    lit = img[img.sum(axis=2) > 80]  # the display, not the background
    left = img[:, :160][img[:, :160].sum(axis=2) > 80]
    right = img[:, 160:][img[:, 160:].sum(axis=2) > 80]
    assert len(lit) > 1000
    np.testing.assert_allclose(left.mean(axis=0), views.lab_to_srgb8(lab[0]), atol=3)
    np.testing.assert_allclose(right.mean(axis=0), views.lab_to_srgb8(lab[2]), atol=3)

    # the picture's top row lies on the far edge: the top of the view from the audience
    top = np.zeros((4, 8), np.uint8)
    top[0] = 255
    img = _decode(views.display_view(top, table, lengths, lab, 33.5,
                                     np.array([0.0, -2.0, 1.7]), width=320))
    lit_rows = np.flatnonzero((img.sum(axis=2) > 80).any(axis=1))
    first, last = img[lit_rows[1]], img[lit_rows[-2]]
    first = first[first.sum(axis=1) > 80].mean(axis=0)
    last = last[last.sum(axis=1) > 80].mean(axis=0)
    np.testing.assert_allclose(first, views.lab_to_srgb8(lab[2]), atol=3)  # far: top row
    np.testing.assert_allclose(last, views.lab_to_srgb8(lab[0]), atol=3)


def test_srgb_encoding_follows_iec_61966_2_1():
    assert views.srgb_encode(np.array([0.0, 0.0031308, 0.18, 1.0, 2.0])).tolist() == \
        [0, 10, 118, 255, 255]
