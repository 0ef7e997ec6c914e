"""The virtual camera: real DNG files read back by rawpy (LibRaw), checked against the scene.

Stated accuracy of the round trip (scene colour -> camera -> DNG -> LibRaw ProPhoto -> Lab) on
the 24 checker patches under a D65-white light, white balance from the checker's grey:
noise-free 14-bit camera max dE00 < 0.2 (12-bit: < 0.6, quantisation of the black patch);
default camera (14 bit, 30000 e- full well, 3 e- read noise)
mean dE00 < 0.35 and max < 1.0 on a 384 x 256 photo.
"""

from __future__ import annotations

import numpy as np
import pytest
import rawpy
from colour import delta_E

from grassd.calib.ccm import fit_ccm
from grassd.calib.charts import get_chart
from grassd.calib.checker_photo import checker_scene, checker_white_balance
from grassd.calib.colour_spaces import (
    luminance,
    prophoto_to_lab,
)
from grassd.calib.errors import DngWriteError
from grassd.calib.raw import develop_raw
from grassd.calib.virtual_camera import CANON_5D2_XYZ_TO_CAMERA, VirtualCamera

CHART = get_chart("spydercheckr-24")
#: The checker's reference colours (two SpyderCheckr patches lie outside Rec.709: the scene
#: keeps them as negative scRGB components and the camera sees their true colour).
REFERENCE = CHART.prophoto()


def _round_trip(tmp_path, camera, light=(1.0, 1.0, 1.0), seed=0, name="c.dng"):
    white = np.asarray(light) * 80.0  # nits of a white card
    img, corners = checker_scene(CHART, white)
    path = camera.photograph(tmp_path / name, img, white, seed=seed)
    wb = checker_white_balance(path, corners, CHART)
    patches = develop_raw(path, white_balance=wb).checker_patches(corners)
    g = CHART.grey_index()
    patches = patches * luminance(REFERENCE[g], "prophoto") / luminance(patches[g], "prophoto")
    return path, patches, delta_E(prophoto_to_lab(patches), prophoto_to_lab(REFERENCE))


def test_noise_free_round_trip_is_exact(tmp_path):
    for kw, limit in (({}, 0.2), ({"cfa_pattern": "GRBG"}, 0.2),
                      ({"bits": 12, "cfa_pattern": "BGGR"}, 0.6)):  # 12 bit: black patch ~40 DN
        cam = VirtualCamera(read_noise_e=0.0, full_well_e=1e9, **kw)
        _, _, de = _round_trip(tmp_path, cam, name=f"{kw['cfa_pattern'] if kw else 'x'}.dng")
        assert de.max() < limit, (kw, de.round(2))


def test_default_camera_round_trip_within_stated_de00(tmp_path):
    path, _, de = _round_trip(tmp_path, VirtualCamera())
    assert de.mean() < 0.35 and de.max() < 1.0, de.round(2)
    with rawpy.imread(str(path)) as raw:
        assert raw.white_level == 16383
        assert list(raw.black_level_per_channel) == [512] * 4
        assert raw.color_desc == b"RGBG"
        # AsShotNeutral = the sensor's response to the white card -> camera multipliers
        n = VirtualCamera().camera_rgb(np.ones(3))
        wb = np.asarray(raw.camera_whitebalance[:3])
        assert wb / wb[1] == pytest.approx(n[1] / n, rel=2e-3)


def test_primaries_differ_from_prophoto_and_ccm_fixes_a_wrong_profile(tmp_path):
    cam = VirtualCamera(read_noise_e=0.0, full_well_e=1e9)
    m = cam.xyz_to_camera / cam.xyz_to_camera.sum(axis=1, keepdims=True)
    assert np.abs(m - np.eye(3)).max() > 0.3  # not a ProPhoto-like sensor
    # a camera profile 30-40 % off in its red row: LibRaw's colours are wrong ...
    wrong = CANON_5D2_XYZ_TO_CAMERA.copy()
    wrong[0] *= [1.4, 0.7, 1.0]
    bad = VirtualCamera(profile=wrong, read_noise_e=0.0, full_well_e=1e9)
    _, patches, de = _round_trip(tmp_path, bad, name="wrong.dng")
    assert de.mean() > 1.0
    # ... and the checker's 3x3 correction removes it
    fit = fit_ccm(REFERENCE, patches)
    assert fit.mean_de00 < 0.2


def test_noise_model_shot_and_read_noise_in_dn(tmp_path):
    cam = VirtualCamera(bits=12, full_well_e=5000.0, read_noise_e=8.0)
    flat = np.full((128, 128, 3), 0.25)
    k = cam.exposure_for(np.ones(3))
    raw = cam.expose(flat, k, np.random.default_rng(3))
    gain = (cam.white_level - cam.black_level_dn) / cam.full_well_e
    signal_e = cam.camera_rgb(flat[0, 0]) * k
    green = raw[0::2, 1::2].astype(float)  # RGGB: (even row, odd column) is green
    expected_mean = cam.black_level_dn + signal_e[1] * gain
    expected_std = np.sqrt(signal_e[1] + 8.0**2) * gain
    assert green.mean() == pytest.approx(expected_mean, rel=2e-3)
    assert green.std() == pytest.approx(expected_std, rel=0.05)
    assert raw.max() <= 4095 and raw.dtype == np.uint16
    # the white card fills white_fraction of the scale in its brightest channel
    white = cam.expose(np.ones((64, 64, 3)), k, np.random.default_rng(0))[0::2, 1::2]
    assert (white.mean() - cam.black_level_dn) / (4095 - cam.black_level_dn) == pytest.approx(
        0.6, abs=0.005)


def test_bad_camera_parameters_raise(tmp_path):
    with pytest.raises(DngWriteError, match="bits"):
        VirtualCamera(bits=10)
    with pytest.raises(DngWriteError, match="CFA"):
        VirtualCamera(cfa_pattern="RGBW")
    with pytest.raises(DngWriteError, match="invertible"):
        VirtualCamera(xyz_to_camera=np.ones((3, 3)))
    with pytest.raises(DngWriteError, match="even"):
        VirtualCamera().photograph(tmp_path / "x.dng", np.ones((5, 6, 3)), np.ones(3))
    with pytest.raises(DngWriteError, match="no signal"):
        VirtualCamera().exposure_for(np.zeros(3))


def _rotated_dng(path, raw, camera, orientation):
    """A DNG like calib.dng.write_dng's, plus an EXIF Orientation tag (as portrait photos
    carry): LibRaw rotates the developed image accordingly."""
    import tifffile

    from grassd.calib.dng import CFA_PATTERNS, _srational

    cam = camera.dng_camera()
    tags = [(33421, "H", 2, (2, 2), True), (33422, "B", 4, bytes(CFA_PATTERNS["RGGB"]), True),
            (271, "s", 0, cam.make, True), (272, "s", 0, cam.model, True),
            (274, "H", 1, orientation, True), (50706, "B", 4, bytes((1, 4, 0, 0)), True),
            (50710, "B", 3, bytes((0, 1, 2)), True), (50714, "I", 1, cam.black_level, True),
            (50717, "I", 1, cam.white_level, True),
            (50721, 10, 9, _srational(cam.color_matrix), True),
            (50728, 5, 3, _srational(cam.neutral()), True), (50778, "H", 1, 21, True)]
    tifffile.imwrite(path, raw, photometric=32803, subfiletype=0, metadata=None,
                     extratags=tags, rowsperstrip=raw.shape[0])
    return path


@pytest.mark.parametrize("orientation, turns", [(6, 1), (8, -1), (3, 2)])
def test_checker_white_balance_on_rotated_photos(tmp_path, orientation, turns):
    cam = VirtualCamera(read_noise_e=0.0, full_well_e=1e9)
    white = np.full(3, 80.0)
    img, corners = checker_scene(CHART, white)
    k = cam.exposure_for(white)
    upright = cam.photograph(tmp_path / "up.dng", img, white, electrons_per_unit=k)
    # the sensor saw the scene turned the other way; LibRaw turns it back on development
    raw = cam.expose(np.rot90(img, turns).copy(), k, np.random.default_rng(0))
    turned = _rotated_dng(tmp_path / "turned.dng", raw, cam, orientation)
    dev = develop_raw(turned, white_balance=(2.0, 1.0, 1.5))
    assert dev.rgb.shape[:2] == img.shape[:2]  # corners refer to this upright image
    wb_up = checker_white_balance(upright, corners, CHART)
    wb_turned = checker_white_balance(turned, corners, CHART)
    assert wb_turned == pytest.approx(wb_up, rel=1e-3)
