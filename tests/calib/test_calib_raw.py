"""RAW captures end to end: tests write real DNG files, rawpy develops them, patches come back.

Tolerance: after normalising exposure on the grey patch, every patch of the developed chart is
within 0.5 dE00 of the colour written (measured: mean 0.015, max 0.08; the budget covers 14-bit
quantisation, demosaicing at patch edges and the 1e-4 rational encoding of the DNG matrices).
"""

from __future__ import annotations

import matplotlib.path
import numpy as np
import pytest
import rawpy

from grassd.calib.ccm import residual_de00
from grassd.calib.charts import spyder_checkr_24
from grassd.calib.colour_spaces import (
    M_CAT_D65_TO_D50,
    M_XYZ_TO_PROPHOTO,
    prophoto_to_xyz,
    xyz_d50_to_d65,
)
from grassd.calib.dng import DngCamera, mosaic, write_dng, write_linear_dng
from grassd.calib.errors import DngWriteError, GeometryError, NonFiniteError, RawReadError
from grassd.calib.exposure import normalise_exposure
from grassd.calib.raw import develop_raw
from grassd.calib.regions import (
    apply_homography,
    checker_patch_quads,
    extract_checker_patches,
    homography,
    quad_mask,
    quad_mean,
)

TOLERANCE_DE00 = 0.5
# A real-camera-like XYZ(D65) -> camera matrix (DNG ColorMatrix style, made up, non-diagonal).
CANONISH = np.array(
    [[0.6722, -0.0635, -0.0963], [-0.4287, 1.2460, 0.2028], [-0.0908, 0.2162, 0.5668]]
)
H, W = 240, 360
CHART_CORNERS = np.array([(52.0, 38.0), (318.0, 58.0), (300.0, 214.0), (40.0, 196.0)])


def _chart_image(prophoto: np.ndarray, background=(0.05, 0.05, 0.05)) -> np.ndarray:
    """(H, W, 3) ProPhoto image of a 4x6 chart seen in perspective; patches fill 80 % cells."""
    hinv = homography(CHART_CORNERS, [(0, 0), (1, 0), (1, 1), (0, 1)])
    yy, xx = np.mgrid[0:H, 0:W]
    uv = apply_homography(hinv, np.stack([xx + 0.5, yy + 0.5], axis=-1))
    u, v = uv[..., 0], uv[..., 1]
    col = np.floor(u * 6).astype(int)
    row = np.floor(v * 4).astype(int)
    fu, fv = u * 6 - col, v * 4 - row
    inside = (
        (u >= 0)
        & (u < 1)
        & (v >= 0)
        & (v < 1)
        & (np.abs(fu - 0.5) < 0.4)
        & (np.abs(fv - 0.5) < 0.4)
    )
    img = np.broadcast_to(np.asarray(background, float), (H, W, 3)).copy()
    idx = np.clip(row, 0, 3) * 6 + np.clip(col, 0, 5)
    img[inside] = prophoto[idx[inside]]
    return img


def _develop_checker(tmp_path, camera: DngCamera, exposure: float, name: str, **kw):
    ref = spyder_checkr_24()
    scene_pp = _chart_image(ref.prophoto())
    xyz_d65 = xyz_d50_to_d65(prophoto_to_xyz(scene_pp))
    path = write_linear_dng(tmp_path / name, xyz_d65, camera, exposure=exposure)
    dev = develop_raw(path, **kw)
    patches = dev.checker_patches(CHART_CORNERS)
    grey = patches[ref.grey_index()]
    # normalise on the grey patch, then put it at the chart's own grey level (Y ~ 0.18)
    y_grey = prophoto_to_xyz(ref.prophoto()[ref.grey_index()])[1]
    return ref, dev, normalise_exposure(patches, grey, target_y=y_grey)


def test_dng_is_read_by_rawpy_with_our_tags(tmp_path):
    cam = DngCamera(color_matrix=CANONISH, cfa_pattern="GRBG", black_level=1024, white_level=15800)
    rgb = np.full((32, 48, 3), 0.25)
    path = write_dng(tmp_path / "calib_tags.dng", mosaic(rgb, cam), cam)
    with rawpy.imread(str(path)) as raw:
        assert raw.raw_image.shape == (32, 48)
        assert list(raw.black_level_per_channel) == [1024] * 4
        assert raw.white_level == 15800
        np.testing.assert_array_equal(raw.raw_image, mosaic(rgb, cam))
        colors = "".join(raw.color_desc.decode()[i] for i in raw.raw_pattern.ravel())
        assert colors[:3] == "GRB"
        wb = np.array(raw.camera_whitebalance[:3])
        np.testing.assert_allclose(wb / wb[1], cam.neutral()[1] / cam.neutral(), rtol=1e-3)


@pytest.mark.parametrize("pattern", ["RGGB", "GRBG"])
def test_develop_recovers_checker_colours_camera_wb(tmp_path, pattern):
    cam = DngCamera(color_matrix=CANONISH, cfa_pattern=pattern, black_level=512, white_level=16383)
    ref, dev, got = _develop_checker(tmp_path, cam, 0.8, f"calib_{pattern}.dng")
    assert dev.rgb.dtype == np.float32 and dev.rgb.shape == (H, W, 3)
    de = residual_de00(got, ref.prophoto())
    print(f"RAW {pattern}: patch dE00 mean {de.mean():.3f} max {de.max():.3f}")
    assert de.max() < TOLERANCE_DE00


def test_develop_with_given_white_balance_and_absolute_level(tmp_path):
    # camera native = ProPhoto primaries with a D65 white (neutral (1, 1, 1)), so unit
    # multipliers are the right white balance and LibRaw's ProPhoto output is the scene itself
    cam = DngCamera(color_matrix=M_XYZ_TO_PROPHOTO @ M_CAT_D65_TO_D50)
    ref = spyder_checkr_24()
    scene_pp = _chart_image(ref.prophoto())
    path = write_linear_dng(
        tmp_path / "calib_rec709cam.dng", xyz_d50_to_d65(prophoto_to_xyz(scene_pp)), cam
    )
    dev = develop_raw(path, white_balance=(1.0, 1.0, 1.0))
    assert dev.white_balance == (1.0, 1.0, 1.0, 1.0)
    patches = dev.checker_patches(CHART_CORNERS)
    # with unit multipliers and exposure 1 the absolute level survives: no normalisation needed
    de = residual_de00(patches, ref.prophoto())
    assert de.max() < TOLERANCE_DE00
    np.testing.assert_allclose(patches, ref.prophoto(), atol=0.004)


def test_truncated_and_non_raw_files_raise_typed_errors(tmp_path):
    cam = DngCamera()
    good = write_linear_dng(tmp_path / "calib_good.dng", np.full((32, 32, 3), 0.2), cam)
    data = good.read_bytes()
    truncated = tmp_path / "calib_truncated.dng"
    truncated.write_bytes(data[: len(data) // 2])
    # LibRaw opens the truncated file; only postprocess fails, and that is guarded too
    with rawpy.imread(str(truncated)):
        pass
    with pytest.raises(RawReadError, match="truncated or corrupt"):
        develop_raw(truncated)
    text = tmp_path / "calib_notes.dng"
    text.write_text("this is not a raw file\n")
    with pytest.raises(RawReadError, match="not a RAW file"):
        develop_raw(text)
    with pytest.raises(RawReadError, match="does not exist"):
        develop_raw(tmp_path / "missing.dng")
    with pytest.raises(RawReadError, match="multipliers"):
        develop_raw(good, white_balance=(1.0, -2.0, 1.0))
    with pytest.raises(RawReadError, match="camera"):
        develop_raw(good, white_balance="auto")


def test_dng_writer_rejects_bad_arguments(tmp_path):
    cam = DngCamera()
    with pytest.raises(DngWriteError, match="even"):
        mosaic(np.zeros((3, 4, 3)), cam)
    with pytest.raises(DngWriteError, match="CFA"):
        mosaic(np.zeros((4, 4, 3)), DngCamera(cfa_pattern="XTRANS"))
    with pytest.raises(DngWriteError, match="black_level"):
        mosaic(np.zeros((4, 4, 3)), DngCamera(black_level=70000))
    with pytest.raises(DngWriteError, match="invertible"):
        write_dng(
            tmp_path / "x.dng",
            np.zeros((4, 4), np.uint16),
            DngCamera(color_matrix=np.zeros((3, 3))),
        )
    with pytest.raises(DngWriteError, match="uint16"):
        write_dng(tmp_path / "x.dng", np.zeros((4, 4)), cam)
    with pytest.raises(DngWriteError, match="gamut"):
        write_linear_dng(
            tmp_path / "x.dng",
            np.full((4, 4, 3), [0.1, 0.8, 0.05]),
            DngCamera(color_matrix=CANONISH * [[1], [1], [-1]]),
        )


def test_quad_mask_matches_matplotlib_path_on_random_convex_quads():
    rng = np.random.default_rng(5)
    yy, xx = np.mgrid[0:60, 0:80]
    centres = np.column_stack([xx.ravel() + 0.5, yy.ravel() + 0.5])
    tested = 0
    for _ in range(60):
        c = rng.uniform([20, 20], [60, 40])
        quad = c + rng.uniform(6, 14) * np.array([(-1, -1), (1, -1), (1, 1), (-1, 1)])
        quad = quad + rng.uniform(-4, 4, (4, 2))
        e = np.roll(quad, -1, axis=0) - quad
        cross = e[:, 0] * np.roll(e, -1, axis=0)[:, 1] - e[:, 1] * np.roll(e, -1, axis=0)[:, 0]
        if not (cross > 0).all():
            continue
        tested += 1
        ours = quad_mask((60, 80), quad)
        ref = matplotlib.path.Path(quad).contains_points(centres).reshape(60, 80)
        assert (ours != ref).sum() == 0
        np.testing.assert_array_equal(ours, quad_mask((60, 80), quad[::-1]))  # either orientation
    assert tested >= 30


def test_quad_mean_and_geometry_errors():
    img = np.zeros((20, 30, 3))
    img[5:10, 10:20] = [0.2, 0.4, 0.6]
    np.testing.assert_allclose(
        quad_mean(img, [(10, 5), (20, 5), (20, 10), (10, 10)]), [0.2, 0.4, 0.6]
    )
    img_nan = img.copy()
    img_nan[7, 12, 1] = np.nan
    with pytest.raises(NonFiniteError, match="inside the quadrilateral"):
        quad_mean(img_nan, [(10, 5), (20, 5), (20, 10), (10, 10)])
    # a NaN outside the area does not matter
    np.testing.assert_allclose(
        quad_mean(img_nan, [(13, 5), (20, 5), (20, 10), (13, 10)]), [0.2, 0.4, 0.6]
    )
    with pytest.raises(GeometryError, match="convex"):
        quad_mean(img, [(10, 5), (20, 10), (20, 5), (10, 10)])  # bow-tie
    with pytest.raises(GeometryError, match="square pixels"):
        quad_mean(img, [(1, 1), (2, 2), (3, 3), (4, 4)])
    with pytest.raises(GeometryError, match="no pixel"):
        quad_mean(img, [(100, 100), (120, 100), (120, 120), (100, 120)])
    with pytest.raises(GeometryError, match="4"):
        quad_mean(img, [(1, 1), (5, 1), (5, 5)])


def test_checker_patches_exact_on_perspective_float_image():
    ref = spyder_checkr_24()
    img = _chart_image(ref.prophoto())
    got = extract_checker_patches(img, CHART_CORNERS)
    np.testing.assert_allclose(got, ref.prophoto(), atol=1e-12)
    quads = checker_patch_quads(CHART_CORNERS)
    assert quads.shape == (24, 4, 2)
    # patch 0 lies near the top-left chart corner, patch 23 near the bottom-right one
    assert np.linalg.norm(quads[0].mean(0) - CHART_CORNERS[0]) < np.linalg.norm(
        quads[0].mean(0) - CHART_CORNERS[2]
    )
    assert np.linalg.norm(quads[23].mean(0) - CHART_CORNERS[2]) < 40


def test_ccm_fixes_a_camera_whose_dng_matrix_is_wrong(tmp_path):
    """Full capture path: sensor response differs from the DNG's ColorMatrix1; a 3x3 CCM fitted
    on the 24 developed patches against the reference chart removes the error."""
    from grassd.calib.ccm import fit_ccm

    ref = spyder_checkr_24()
    sensor = CANONISH
    claimed = CANONISH @ np.array([[1.06, -0.04, 0.0], [0.03, 0.95, 0.02], [0.0, 0.05, 1.04]])
    cam = DngCamera(color_matrix=claimed, cfa_pattern="RGGB")
    xyz = xyz_d50_to_d65(prophoto_to_xyz(_chart_image(ref.prophoto())))
    neutral = sensor @ xyz_d50_to_d65(prophoto_to_xyz(np.ones(3)))
    raw = mosaic(xyz @ sensor.T, cam, exposure=0.8)
    path = write_dng(
        tmp_path / "calib_wrong_matrix.dng", raw, cam, as_shot_neutral=neutral / neutral.max()
    )
    patches = develop_raw(path).checker_patches(CHART_CORNERS)
    y_grey = prophoto_to_xyz(ref.prophoto()[ref.grey_index()])[1]
    captured = normalise_exposure(patches, patches[ref.grey_index()], target_y=y_grey)
    before = residual_de00(captured, ref.prophoto())
    fit = fit_ccm(captured, ref.prophoto())
    print(
        f"RAW wrong-matrix camera: dE00 mean before CCM {before.mean():.2f}, "
        f"after {fit.mean_de00:.3f} (max {fit.max_de00:.3f})"
    )
    assert before.mean() > 1.0
    assert fit.mean_de00 < 0.2 and fit.max_de00 < TOLERANCE_DE00
