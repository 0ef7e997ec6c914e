"""sim.display_photo: the analytic equirect photo of a flat display seen by a 360 camera."""

from __future__ import annotations

import time

import numpy as np
import pytest

from grassd.sim.display_photo import (
    camera_rotation,
    display_footprint,
    display_photo,
    project_to_equirect,
    top_corners_mm,
)
from grassd.sim.errors import SceneError
from grassd.sim.lighting import env_radiance, uv_to_direction
from grassd.sim.scene import DisplaySpec, PixelSpec

DISPLAY = DisplaySpec(rows=4, cols=8, pitch_mm=33.5)
GAPPED = DisplaySpec(PixelSpec(top_mm=30.0), rows=3, cols=5, pitch_mm=40.0)


def _env(seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).uniform(0.1, 2.0, (32, 64, 3))


def _radiance(n: int, seed: int = 1) -> np.ndarray:
    return np.random.default_rng(seed).uniform(0.05, 0.5, (n, 3))


@pytest.mark.parametrize(("camera", "yaw", "display"), [
    ((0.15, -0.9, 0.7), 30.0, DISPLAY),
    ((0.15, -0.9, 0.7), 99.46, DISPLAY),  # the display straddles the seam
    ((0.02, -0.01, 0.4), -75.0, DISPLAY),  # camera above the display: holds the nadir
    ((-0.6, 0.3, 0.3), 180.0, GAPPED),
])
def test_the_cropped_render_equals_tracing_every_texel(camera, yaw, display):
    rad = _radiance(display.rows * display.cols)
    kw = dict(frame_radiance=(0.01, 0.02, 0.03), width=512, height=256, supersample=3)
    cropped = display_photo(_env(), camera, yaw, display, rad, **kw)
    full = display_photo(_env(), camera, yaw, display, rad, crop=False, **kw)
    assert np.array_equal(cropped, full)
    assert (np.abs(full - display_photo(_env(), camera, yaw, display, rad * 0 + 7.0,
                                        **kw)).max(axis=2) > 0).sum() > 20  # display visible


def test_the_seam_straddling_footprint_wraps_round_the_columns():
    _, _, cols = display_footprint(DISPLAY, (0.15, -0.9, 0.7), 99.46, 512, 256)
    assert 0 in cols and 511 in cols and len(cols) < 100


def test_the_background_is_the_env_seen_in_world_directions_at_texel_centres():
    env, yaw, w, h = _env(3), 37.0, 256, 128
    img = display_photo(env, (0.0, -1.0, 0.8), yaw, DISPLAY, _radiance(32), width=w, height=h)
    rows, cols = np.mgrid[0:h, 0:w]
    world = uv_to_direction((cols + 0.5) / w, (rows + 0.5) / h) @ camera_rotation(yaw)
    ref = env_radiance(env, world)
    row0, row1, fcols = display_footprint(DISPLAY, (0.0, -1.0, 0.8), yaw, w, h)
    outside = np.ones((h, w), dtype=bool)
    outside[row0:row1, fcols] = False
    assert np.array_equal(img[outside], ref[outside])


def test_a_texel_well_inside_a_pixel_top_has_that_pixels_radiance():
    camera, yaw = np.array([0.15, -0.9, 0.7]), 30.0
    rad = _radiance(32)
    img = display_photo(_env(), camera, yaw, DISPLAY, rad, width=4096, height=2048)
    centres = np.column_stack([DISPLAY.pixel_centres_m(), np.zeros(32)])
    rc = project_to_equirect(centres, camera, yaw, 4096, 2048).astype(int)
    assert np.allclose(img[rc[:, 0], rc[:, 1]], rad)


def test_an_edge_texel_mixes_pixel_and_background_by_the_covered_fraction():
    # black env and frame, radiance 1 on every top: the image sum is the covered texel area
    camera, yaw, w, h = (0.0, -0.8, 0.9), 0.0, 2048, 1024
    img = display_photo(np.zeros((8, 16, 3)), camera, yaw, GAPPED, np.ones((15, 3)),
                        width=w, height=h, supersample=8)[..., 0]
    tops = top_corners_mm(GAPPED) / 1000.0
    # solid angle of the tops (fine numeric integration) vs the image's texel solid angles
    theta = np.pi * (np.arange(h) + 0.5) / h
    omega = (2 * np.pi / w) * (np.pi / h) * np.sin(theta)
    rendered = float((img * omega[:, None]).sum())
    n = 400
    g = (np.arange(n) + 0.5) / n
    total = 0.0
    for q in tops:
        x = q[0, 0] + (q[1, 0] - q[0, 0]) * g
        y = q[0, 1] + (q[3, 1] - q[0, 1]) * g
        xx, yy = np.meshgrid(x, y)
        r2 = (xx - camera[0]) ** 2 + (yy - camera[1]) ** 2 + camera[2] ** 2
        da = ((q[1, 0] - q[0, 0]) / n) * ((q[3, 1] - q[0, 1]) / n)
        total += float((camera[2] / r2**1.5).sum() * da)
    assert rendered == pytest.approx(total, rel=2e-3)


def test_a_camera_below_the_display_or_a_wrong_radiance_shape_is_refused():
    with pytest.raises(SceneError, match="above the display"):
        display_photo(_env(), (0, -1, -0.2), 0.0, DISPLAY, _radiance(32))
    with pytest.raises(SceneError, match=r"\(32, 3\)"):
        display_photo(_env(), (0, -1, 0.5), 0.0, DISPLAY, _radiance(31))


def test_render_time_at_4096_prints(capsys):
    env = _env()
    t = time.perf_counter()
    display_photo(env, (0.15, -0.9, 0.7), 30.0, DISPLAY, _radiance(32))
    with capsys.disabled():
        print(f"\ndisplay_photo 4096 x 2048: {time.perf_counter() - t:.2f} s")
