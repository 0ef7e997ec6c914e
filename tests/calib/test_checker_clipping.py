"""Every checker path refuses a photo whose patches clip, near the white level or at 0, on
DNGs written by the virtual camera."""

from __future__ import annotations

import numpy as np
import pytest
import rawpy

from grassd.calib.charts import get_chart
from grassd.calib.checker_photo import (
    checker_clipping,
    checker_photo_patches,
    checker_scene,
    checker_white_balance,
    refuse_clipped_checker,
)
from grassd.calib.colour_spaces import M_REC709_TO_XYZ, prophoto_to_rec709
from grassd.calib.errors import CheckerPhotoError, ClippedCheckerError, CornersOutsideImageError
from grassd.calib.raw import develop_raw
from grassd.calib.regions import checker_patch_quads, quad_values
from grassd.calib.virtual_camera import VirtualCamera

SPYDER = get_chart("spydercheckr-24")
WARM = np.array([1.0, 0.85, 0.65]) * 80.0  # white card radiance, nits
#: A sensor that *is* Rec.709 and cuts negative responses at 0 (out-of-gamut patches go dark).
REC709_SENSOR = np.linalg.inv(M_REC709_TO_XYZ)


def _shot(tmp_path, name, cam=None, over=1.0, chart=SPYDER):
    img, corners = checker_scene(chart, WARM)
    cam = cam or VirtualCamera(read_noise_e=0.0, full_well_e=1e9)
    path = cam.photograph(tmp_path / name, img, WARM,
                          electrons_per_unit=over * cam.exposure_for(WARM))
    return path, corners


def test_a_well_exposed_checker_passes_every_path(tmp_path):
    path, corners = _shot(tmp_path, "good.dng", VirtualCamera())  # with read and shot noise
    clip = checker_clipping(path, corners)
    assert not clip.clipped and clip.high == () and clip.low == ()
    refuse_clipped_checker(path, corners, SPYDER)
    wb = checker_white_balance(path, corners, SPYDER)
    patches = checker_photo_patches(path, corners, SPYDER, white_balance=wb)
    expect = develop_raw(path, white_balance=wb).checker_patches(corners)
    np.testing.assert_array_equal(patches, expect)
    assert (patches > 0).all()


def test_over_exposure_names_the_light_patches_and_says_lower_the_exposure(tmp_path):
    path, corners = _shot(tmp_path, "over.dng", over=2.5)
    for call in (lambda: checker_white_balance(path, corners, SPYDER),
                 lambda: checker_photo_patches(path, corners, SPYDER),
                 lambda: refuse_clipped_checker(path, corners, SPYDER, None)):
        with pytest.raises(ClippedCheckerError, match="near the white level") as err:
            call()
        assert isinstance(err.value, CheckerPhotoError)
        assert "lower the exposure" in str(err.value)
        white = int(np.argmax(SPYDER.lab[:, 0]))
        assert white in err.value.high and err.value.low == ()
        assert f"{white + 1} ({SPYDER.patch_names[white]}) in " in str(err.value)
        assert SPYDER.grey_index() not in err.value.high


def test_just_below_the_white_level_is_clipped_too(tmp_path):
    cam = VirtualCamera(read_noise_e=0.0, full_well_e=1e9, white_fraction=1.0)
    white = int(np.argmax(SPYDER.lab[:, 0]))
    albedo = prophoto_to_rec709(SPYDER.prophoto()[white])
    share = float(cam.camera_rgb(albedo * WARM).max() / cam.camera_rgb(WARM).max())
    # the white patch at 99 % of full scale: above the 98 % margin, below the white level
    path, corners = _shot(tmp_path, "edge.dng", cam, over=0.99 / share)
    with rawpy.imread(str(path)) as raw:
        data, top = raw.raw_image_visible.copy(), raw.white_level
    assert quad_values(data, checker_patch_quads(corners)[white]).max() < top
    assert checker_clipping(path, corners, None).high == (white,)
    # and at 96 % it passes
    path, corners = _shot(tmp_path, "edge2.dng", cam, over=0.96 / share)
    assert not checker_clipping(path, corners, None).clipped


def test_a_white_balance_that_saturates_the_development_is_refused(tmp_path):
    # raw values far below the white level, but a red multiplier 6x the smallest: LibRaw
    # scales red by 6 and clips it at full scale in the developed image
    path, corners = _shot(tmp_path, "wb.dng")
    wb = (6.0, 1.0, 1.0, 1.0)
    assert not checker_clipping(path, corners, None).clipped
    clip = checker_clipping(path, corners, wb)
    white = int(np.argmax(SPYDER.lab[:, 0]))
    assert white in clip.high and "R" in clip.high_filters[clip.high.index(white)]
    with pytest.raises(ClippedCheckerError, match="lower the exposure"):
        checker_photo_patches(path, corners, SPYDER, white_balance=wb)
    # the premise: the development really saturates red on that patch
    with rawpy.imread(str(path)) as raw:
        dev = raw.postprocess(output_color=rawpy.ColorSpace.raw, gamma=(1, 1),
                              no_auto_bright=True, output_bps=16, adjust_maximum_thr=0.0,
                              user_wb=list(wb))
    assert quad_values(dev[..., 0], checker_patch_quads(corners)[white]).max() == 65535


@pytest.mark.parametrize("read_noise", [0.0, 3.0])
def test_a_sensor_cutting_negative_responses_at_0_is_refused(tmp_path, read_noise):
    cam = VirtualCamera(xyz_to_camera=REC709_SENSOR, read_noise_e=read_noise)
    path, corners = _shot(tmp_path, "rec709.dng", cam)
    # SpyderCheckr B1 (red) and B3 (blue) lie outside Rec.709: their channel reads nothing
    b1, b3 = SPYDER.patch_names.index("B1"), SPYDER.patch_names.index("B3")
    clip = checker_clipping(path, corners)
    assert clip.low == (b1, b3) and clip.low_filters == ("R", "B") and clip.high == ()
    with pytest.raises(ClippedCheckerError, match="clipped at 0") as err:
        checker_white_balance(path, corners, SPYDER)
    assert err.value.low == (b1, b3)
    assert f"{b1 + 1} (B1) in R" in str(err.value) and "non-negative" in str(err.value)
    with pytest.raises(ClippedCheckerError, match="clipped at 0"):
        checker_photo_patches(path, corners, SPYDER)


def test_dark_patches_of_a_dim_but_unclipped_shot_pass(tmp_path):
    # a fifth of the usual exposure: the black patch (~3 %) still reads ~2 % of full scale
    path, corners = _shot(tmp_path, "dim.dng", VirtualCamera(), over=0.2)
    assert not checker_clipping(path, corners).clipped


def test_corners_outside_the_photo_still_say_so(tmp_path):
    path, corners = _shot(tmp_path, "good.dng")
    far = np.asarray(corners) + [5000.0, 0.0]
    with pytest.raises(CornersOutsideImageError, match="outside"):
        checker_clipping(path, far)
    with pytest.raises(CornersOutsideImageError, match="outside"):
        checker_photo_patches(path, far, SPYDER)
