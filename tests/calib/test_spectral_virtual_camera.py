"""The virtual camera with non-negative spectral sensitivities: no negative response to any
light, checker photos no checker path refuses, and the colour correction fitted to them."""

from __future__ import annotations

import numpy as np
import pytest

from grassd.calib.camera_response import WAVELENGTHS, CameraSensitivities
from grassd.calib.ccm import select_ccm
from grassd.calib.charts import get_chart
from grassd.calib.checker_photo import (
    checker_clipping,
    checker_photo_patches,
    checker_scene,
    checker_white_balance,
    virtual_checker,
)
from grassd.calib.colour_spaces import M_REC709_TO_XYZ, luminance
from grassd.calib.errors import CameraResponseError, ClippedCheckerError
from grassd.calib.exposure import GREY_CARD_Y
from grassd.calib.spectral_virtual_camera import (
    SpectralVirtualCamera,
    chart_reflectances,
    mallett_basis,
    spectral_checker_scene,
)
from grassd.calib.virtual_camera import VirtualCamera

SPYDER = get_chart("spydercheckr-24")
CLASSIC = get_chart("colorchecker-classic")


@pytest.mark.parametrize("light", ["D65", "A"])
def test_no_light_reads_below_zero_and_nothing_is_clipped(light):
    cam = SpectralVirtualCamera(light=light)
    assert (cam.response_matrix >= 0).all()
    rng = np.random.default_rng(0)
    rgb = np.vstack([np.eye(3), rng.uniform(0, 1, (500, 3)) ** 3]) * cam.light_rgb709
    unclipped = (rgb / cam.light_rgb709) @ cam.response_matrix.T
    assert (unclipped >= 0).all()
    np.testing.assert_array_equal(cam.camera_rgb(rgb), unclipped)
    # the Canon 3x3 and a Rec.709 sensor both go negative on saturated light
    for m in (VirtualCamera().xyz_to_camera, np.linalg.inv(M_REC709_TO_XYZ)):
        assert ((rgb @ (m @ M_REC709_TO_XYZ).T) < 0).any()


def test_the_response_is_that_of_a_spectrum_of_the_same_colour():
    cam = SpectralVirtualCamera(light="A")
    a = np.array([[0.2, 0.5, 0.1], [0.9, 0.3, 0.6]])
    spectra = a @ mallett_basis().T
    np.testing.assert_allclose(cam.camera_rgb(a * cam.light_rgb709),
                               cam.response_to_reflectance(spectra), rtol=1e-12)
    # a white card fills white_fraction of the full well in its brightest channel
    k = cam.exposure_for(cam.light_rgb709)
    assert k * cam.camera_rgb(cam.light_rgb709).max() == pytest.approx(
        cam.white_fraction * cam.full_well_e)
    # the DNG's profile is the camera's maker-style matrix, not its true response
    np.testing.assert_allclose(cam.dng_camera().color_matrix,
                               cam.sensitivities.xyz_to_camera)


def test_a_rec709_sensor_is_refused_where_the_spectral_one_passes(tmp_path):
    white = np.array([1.0, 0.9, 0.75]) * 80.0
    img, corners = checker_scene(SPYDER, white)
    rec709 = VirtualCamera(xyz_to_camera=np.linalg.inv(M_REC709_TO_XYZ))
    with pytest.raises(ClippedCheckerError, match="clipped at 0"):
        checker_white_balance(rec709.photograph(tmp_path / "rec709.dng", img, white),
                              corners, SPYDER)
    cam = SpectralVirtualCamera()
    path = cam.photograph(tmp_path / "spectral.dng", img, white)
    assert not checker_clipping(path, corners).clipped
    wb = checker_white_balance(path, corners, SPYDER)
    assert checker_photo_patches(path, corners, SPYDER, wb).min() > 0


def _fitted(path, corners, chart):
    wb = checker_white_balance(path, corners, chart)
    patches = checker_photo_patches(path, corners, chart, wb)
    k = GREY_CARD_Y / float(luminance(patches[chart.grey_index()], "prophoto"))
    return select_ccm(virtual_checker(chart)[0], patches * k)


@pytest.mark.parametrize("light", ["D65", "A"])
def test_measured_checker_spectra_photographed_and_corrected(tmp_path, light):
    cam = SpectralVirtualCamera(light=light, read_noise_e=0.0, full_well_e=1e9)
    img, white, corners = spectral_checker_scene(cam)
    path = cam.photograph_camera_rgb(tmp_path / "classic.dng", img, white)
    best = _fitted(path, corners, CLASSIC)
    print(f"\nNikon, measured ColorChecker spectra, {light}, via DNG: " + ", ".join(
        f"{s.form} fit {s.fit_mean_de00:.2f} loo {s.loo_mean_de00:.2f}/{s.loo_max_de00:.2f}"
        for s in best.candidates))
    assert best.loo_mean_de00 == min(s.loo_mean_de00 for s in best.candidates)
    assert best.loo_mean_de00 < 3.0


def test_bad_checker_spectra_are_typed():
    cam = SpectralVirtualCamera()
    with pytest.raises(CameraResponseError, match="24"):
        spectral_checker_scene(cam, reflectances=np.ones((23, len(WAVELENGTHS))))
    with pytest.raises(CameraResponseError, match="unknown illuminant"):
        SpectralVirtualCamera(light="D66")
    sigma = SpectralVirtualCamera(sensitivities=CameraSensitivities.from_colour(
        "sigma-sdmerrill"))
    assert (sigma.response_matrix >= 0).all()


@pytest.mark.long
def test_spydercheckr_spectra_recovered_and_corrected(tmp_path):
    refl = chart_reflectances(SPYDER)
    assert refl.shape == (24, len(WAVELENGTHS)) and (refl >= 0).all() and (refl <= 1).all()
    cam = SpectralVirtualCamera(read_noise_e=0.0, full_well_e=1e9)
    img, white, corners = spectral_checker_scene(cam, reflectances=refl)
    best = _fitted(cam.photograph_camera_rgb(tmp_path / "spyder.dng", img, white), corners,
                   SPYDER)
    print("\nNikon, SpyderCheckr (Jakob-Hanika spectra), D65, via DNG: " + ", ".join(
        f"{s.form} fit {s.fit_mean_de00:.2f} loo {s.loo_mean_de00:.2f}/{s.loo_max_de00:.2f}"
        for s in best.candidates))
    assert best.loo_mean_de00 < 0.5


@pytest.mark.parametrize("light", ["D65", "A"])
def test_a_correction_predicted_from_the_sensitivities_matches_the_photo(tmp_path, light):
    from grassd.calib.camera_response import (
        camera_correction,
        checker_reflectances,
        simulation_rec709,
    )
    from grassd.calib.ccm import residual_de00
    from grassd.calib.checker_photo import raw_rgb_cam
    from grassd.calib.colour_spaces import rec709_to_prophoto

    _, refl = checker_reflectances()
    grey = 21  # neutral 5 (.70 D) of the ColorChecker
    for name, cam in (("luther", _luther()), ("nikon", None)):
        camera = SpectralVirtualCamera(light=light, read_noise_e=0.0, full_well_e=1e9,
                                       **({} if cam is None else {"sensitivities": cam}))
        img, white, corners = spectral_checker_scene(camera)
        path = camera.photograph_camera_rgb(tmp_path / f"{name}.dng", img, white)
        wb = checker_white_balance(path, corners, CLASSIC)
        photo = checker_photo_patches(path, corners, CLASSIC, wb)
        out = {}
        for transport in ("rgb", "spectral"):
            w = simulation_rec709(np.ones(len(WAVELENGTHS)), light, transport)
            sim = rec709_to_prophoto(simulation_rec709(refl, light, transport) / w)
            corr = camera_correction(camera.sensitivities, light, wb, raw_rgb_cam(path),
                                     sim[grey], transport)
            pred = np.clip(corr.apply(sim), 0.0, None)
            k = luminance(pred[grey], "prophoto") / luminance(photo[grey], "prophoto")
            out[transport] = residual_de00(pred, photo * k)
        print(f"\n{name} {light} predicted correction: " + ", ".join(
            f"{t} {d.mean():.2f}/{d.max():.2f}" for t, d in out.items()))
        if name == "luther":  # a colorimetric camera is predicted exactly by spectral light
            assert out["spectral"].mean() < 0.05 and out["spectral"].max() < 0.3  # 14-bit DNG
        else:
            assert out["spectral"].mean() < 1.5
        assert out["spectral"].mean() <= out["rgb"].mean() + 0.02


def _luther() -> CameraSensitivities:
    from grassd.calib.camera_response import cie_observer

    mix = np.array([[0.6, 0.4, 0.0], [0.1, 0.9, 0.0], [0.0, 0.1, 0.9]])
    return CameraSensitivities("luther", cie_observer() @ mix.T, (380.0, 780.0))
