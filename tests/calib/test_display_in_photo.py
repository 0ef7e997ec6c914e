"""calib.display_in_photo: find a display in a 360 photo pair, solve the camera pose, sample
every pixel's top. Photos: sim.display_photo over a real HDRI, 4096 x 2048, 1 % noise."""

from __future__ import annotations

import time

import numpy as np
import pytest

from grassd.calib.display_in_photo import (
    DisplayNotFoundError,
    PoseError,
    locate_display,
    pixel_means,
    solve_pose,
)
from grassd.calib.errors import GeometryError
from grassd.sim.display_photo import camera_rotation, display_photo
from grassd.sim.hdri import load_hdri
from grassd.sim.lighting import uv_to_direction
from grassd.sim.scene import DisplaySpec

DISPLAY = DisplaySpec(rows=4, cols=8, pitch_mm=33.5)
W, H = 4096, 2048
RNG = np.random.default_rng(31)
SHORT = np.array([0.21, 0.27, 0.09]) * RNG.uniform(0.9, 1.1, (32, 1))  # yellow-green
LONG = np.array([0.07, 0.18, 0.05]) * RNG.uniform(0.9, 1.1, (32, 1))  # green
FRAME = (0.03, 0.03, 0.03)

# (camera position m, yaw deg): the brief's pose, off-centre, shallow (25 deg elevation),
# yaw 180, and the display straddling the equirect seam (yaw = the display's azimuth)
POSES = {
    "front": ((0.15, -0.9, 0.7), 30.0),
    "off_centre": ((0.55, -0.75, 0.65), -20.0),
    "shallow_25deg": ((-0.1, -1.2, 0.56), 180.0),
    "on_the_seam": ((0.15, -0.9, 0.7), float(np.degrees(np.arctan2(0.9, -0.15)))),
}


@pytest.fixture(scope="module")
def env(shared_hdri):
    return load_hdri(shared_hdri("courtyard"))[::2, ::2]


def _photos(env, camera, yaw, seed=0):
    rng = np.random.default_rng(seed)
    out = []
    for rad in (SHORT, LONG):
        img = display_photo(env, camera, yaw, DISPLAY, rad, frame_radiance=FRAME, width=W,
                            height=H)
        img *= 1.0 + 0.01 * rng.standard_normal(img.shape, dtype=np.float32)
        out.append(img)
    return out


@pytest.fixture(scope="module")
def located(env):
    """{pose name: (photos, DisplayInPhoto, seconds to locate)}."""
    out = {}
    for name, (camera, yaw) in POSES.items():
        short, long = _photos(env, camera, yaw)
        t = time.perf_counter()
        loc = locate_display(short, long, DISPLAY.rows, DISPLAY.cols, DISPLAY.pitch_mm,
                             DISPLAY.pixel.top_mm)
        out[name] = ((short, long), loc, time.perf_counter() - t)
    return out


@pytest.mark.parametrize("name", POSES)
def test_the_camera_pose_is_recovered_within_a_centimetre(located, name, capsys):
    camera, yaw = POSES[name]
    _, loc, seconds = located[name]
    err = np.linalg.norm(loc.pose.position_m - np.array(camera))
    r = loc.pose.rotation @ camera_rotation(yaw).T
    angle = np.degrees(np.arccos(np.clip((np.trace(r) - 1) / 2, -1, 1)))
    with capsys.disabled():
        print(f"\n{name}: position error {1000 * err:.2f} mm, rotation error {angle:.3f} deg, "
              f"rms {loc.pose.rms_deg:.4f} deg, locate + pose {seconds:.2f} s")
    assert err < 0.01
    assert angle < 0.5
    assert loc.pose.rms_deg < 0.05
    assert abs((loc.pose.yaw_deg - yaw + 180) % 360 - 180) < 0.5


@pytest.mark.parametrize("name", POSES)
def test_every_sampling_region_is_non_empty_and_inside_its_true_top(located, name):
    """Every corner of every sampled texel, traced from the true camera, hits the true top
    square of the pixel it is sampled for."""
    camera, yaw = POSES[name]
    _, loc, _ = located[name]
    sizes = loc.region_sizes()
    assert sizes.min() >= 20
    cam = np.array(camera)
    half = DISPLAY.pixel.top_mm / 2000.0
    centres = DISPLAY.pixel_centres_m()[loc.texel_pixel]
    for dr, dc in ((0, 0), (0, 1), (1, 0), (1, 1)):
        d = uv_to_direction((loc.texel_cols + dc) / W, (loc.texel_rows + dr) / H)
        d = d @ camera_rotation(yaw)  # camera frame -> world
        assert (d[:, 2] < 0).all()
        hit = cam[:2] + (-cam[2] / d[:, 2])[:, None] * d[:, :2]
        assert (np.abs(hit - centres) <= half).all()


@pytest.mark.parametrize("name", POSES)
def test_pixel_means_match_the_rendered_radiance_within_one_percent(located, name):
    (short, long), loc, _ = located[name]
    assert np.abs(pixel_means(short, loc) / SHORT - 1).max() < 0.01
    assert np.abs(pixel_means(long, loc) / LONG - 1).max() < 0.01


def test_corner_bearings_and_centre_bearings_point_at_the_display(located):
    camera, yaw = POSES["front"]
    _, loc, _ = located["front"]
    pts = np.column_stack([loc.corners_mm / 1000.0, np.zeros(4)])
    true = (pts - camera) @ camera_rotation(yaw).T
    true /= np.linalg.norm(true, axis=1, keepdims=True)
    texel = np.radians(360.0 / W)
    assert np.arccos(np.clip(np.sum(true * loc.corner_bearings, 1), -1, 1)).max() < 0.3 * texel
    assert loc.corners_mm[0].tolist() == [-134.0, -67.0]


def test_photos_that_do_not_differ_say_so(env):
    camera, yaw = POSES["front"]
    short, _ = _photos(env, camera, yaw, seed=1)
    again, _ = _photos(env, camera, yaw, seed=2)
    with pytest.raises(DisplayNotFoundError, match="differ nowhere above noise"):
        locate_display(short, again, 4, 8, 33.5, 33.5)


@pytest.mark.parametrize(("rows", "cols"), [(4, 4), (2, 8), (4, 12), (4, 9)])
def test_a_wrong_rows_or_cols_is_refused_by_the_shape_found(located, rows, cols):
    (short, long), _, _ = located["front"]
    with pytest.raises(DisplayNotFoundError, match=rf"shape of a {rows} x {cols} display.*"
                                                   r"measured (1\.9|2)"):
        locate_display(short, long, rows, cols, 33.5, 33.5)


def test_bad_arguments_are_refused():
    img = np.zeros((8, 16, 3))
    with pytest.raises(GeometryError, match="equirect"):
        locate_display(img, img, 4, 8, 33.5, 33.5, projection="fisheye")
    with pytest.raises(GeometryError, match="width = 2 x height"):
        locate_display(img[:, :10], img[:, :10], 4, 8, 33.5, 33.5)


# ------------------------------------------------------------------------------ solve_pose


def _truth(camera=(0.3, -1.1, 0.8), yaw=-40.0, n=30, seed=0):
    rng = np.random.default_rng(seed)
    pts = np.column_stack([rng.uniform(-0.2, 0.2, (n, 2)), np.zeros(n)])
    b = (pts - camera) @ camera_rotation(yaw).T
    return b / np.linalg.norm(b, axis=1, keepdims=True), pts


def test_solve_pose_recovers_an_exact_pose_from_exact_bearings():
    b, pts = _truth()
    pose = solve_pose(b, pts)
    assert np.allclose(pose.position_m, [0.3, -1.1, 0.8], atol=1e-9)
    assert np.allclose(pose.rotation, camera_rotation(-40.0), atol=1e-9)
    assert pose.rms_deg < 1e-6 and pose.n_points == 30


def test_solve_pose_refuses_mirrored_points_and_mismatched_ones():
    b, pts = _truth()
    with pytest.raises(PoseError, match="below the display"):
        solve_pose(b, pts * [1, -1, 1])
    with pytest.raises(PoseError, match="residual"):
        solve_pose(b, pts[np.random.default_rng(1).permutation(len(pts))])
    with pytest.raises(PoseError, match="at least 4"):
        solve_pose(b[:3], pts[:3])
