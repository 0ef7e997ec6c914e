"""validate and fit read through the camera's spectral sensitivities (``camera_sensitivities``
in capture.toml): the manifest key, its errors, and a world where the prediction is exact.

A grey pixel under a uniform white sky reflects only white light, whose spectrum every
upsampling gives as D65. The camera (a
:class:`~grassd.calib.spectral_virtual_camera.SpectralVirtualCamera` with the Nikon D5100's
sensitivities) responds linearly to Rec.709 light, so the checker's correction is exact for it;
the camera chain, fitted to nothing, must then read the pixel as the correction does.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from colour import delta_E

from grassd.calib.camera_response import CameraSensitivities, write_sensitivities
from grassd.calib.spectral_virtual_camera import SpectralVirtualCamera
from grassd.daemon.core.calibration.transport import light_spectra_basis
from grassd.daemon.offline.validate import (
    MANIFEST_NAME,
    CaptureManifestError,
    MissingPhotoError,
    ValidateError,
    load_manifest,
    manifest_to_toml,
    validate_capture,
)
from grassd.daemon.offline.virtual_capture import capture_world
from grassd.sim.hdri import write_exr
from grassd.sim.light_input import LightInput

LENGTHS = (0.0, 6.0, 12.0, 20.0)
GREY = {"yellow_srgb": (150.0, 150.0, 150.0), "green_srgb": (110.0, 110.0, 110.0),
        "base_srgb": (80.0, 80.0, 80.0)}


@pytest.fixture(scope="module")
def grey_capture(tmp_path_factory, renderer):
    from grassd.sim.scene import PixelSpec

    root = tmp_path_factory.mktemp("grey")
    write_exr(root / "sky.exr", np.ones((16, 32, 3), np.float32))
    light = LightInput(root / "sky.exr", 800.0)
    pixel = PixelSpec(**GREY)
    m = capture_world(root / "capture", light, [(170.0, 2.0, 0.0)], LENGTHS, real_pixel=pixel,
                      model_pixel=GREY, camera=SpectralVirtualCamera(), renderer=renderer,
                      width=96, spp=16)
    return m


def _with_key(m, value: str) -> None:
    (m.root / MANIFEST_NAME).write_text(manifest_to_toml(replace(m, sensitivities=value)))


def test_the_key_names_a_camera_or_a_csv_beside_the_photos(grey_capture):
    m = grey_capture
    _with_key(m, "nikon-d5100")
    assert load_manifest(m.root).sensitivities == "nikon-d5100"
    write_sensitivities(m.root / "nikon.csv", CameraSensitivities.from_colour("nikon-d5100"))
    _with_key(m, str((m.root / "nikon.csv").resolve()))
    text = (m.root / MANIFEST_NAME).read_text()
    assert 'camera_sensitivities = "nikon.csv"' in text  # written relative to the capture
    assert load_manifest(m.root).sensitivities == str((m.root / "nikon.csv").resolve())
    _with_key(m, "canon.csv")
    with pytest.raises(MissingPhotoError, match="camera_sensitivities .*canon.csv does not "
                                                "exist.*nikon-d5100"):
        load_manifest(m.root)
    (m.root / MANIFEST_NAME).write_text(
        (m.root / MANIFEST_NAME).read_text().replace('"canon.csv"', '""'))
    with pytest.raises(CaptureManifestError, match="camera_sensitivities"):
        load_manifest(m.root)
    (m.root / MANIFEST_NAME).write_text(manifest_to_toml(m))
    with pytest.raises(ValidateError, match="leave out the target standard error"):
        validate_capture(replace(m, sensitivities="nikon-d5100"), target_stderr=0.1)


def test_a_grey_pixel_is_predicted_without_a_correction(grey_capture, renderer):
    from grassd.sim.scene import RenderSettings

    m = replace(grey_capture, sensitivities="nikon-d5100")
    lighting = m.light.lighting()
    settings = RenderSettings(samples=4096, replicates=4)
    camera = validate_capture(m, renderer=renderer, settings=settings, lighting=lighting)
    corrected = validate_capture(replace(m, sensitivities=None), renderer=renderer,
                                 settings=settings, lighting=lighting)
    assert camera.chain == "camera" and camera.to_json()["colour_chain"] == "camera"
    assert corrected.chain == corrected.ccm.form
    (v,) = camera.viewpoints
    (c,) = corrected.viewpoints
    de = delta_E(v.sim_lab, c.sim_lab, method="CIE 2000")
    print(f"grey pixel: camera chain vs correction dE00 {np.round(de, 3)}; photos vs camera "
          f"chain {np.round(delta_E(v.real_lab, v.sim_lab), 3)}, Frechet {v.frechet:.3f}")
    assert de.max() < 0.2, de  # the correction's leave-one-out noise and the chain's quadrature
    assert v.frechet < 0.3
    # the photos against either chain: the harness's own preview-vs-trace difference, as in
    # test_validate_world's zero-difference world
    assert delta_E(v.real_lab, v.sim_lab).max() < 2.0


def test_a_uniform_sky_has_one_spectrum_for_its_one_colour(grey_capture):
    """Every texel of one colour: the basis still gives that colour its own spectrum
    (the least squares is singular there; the constraints alone decide)."""
    lighting = grey_capture.light.lighting()
    b = light_spectra_basis(lighting)
    white = b @ np.ones(3)
    assert np.isfinite(b).all()
    from grassd.calib.spectral_prediction import emitter_spectra

    expected = emitter_spectra(np.ones(3))
    np.testing.assert_allclose(white / white.max(), expected / expected.max(), atol=1e-6)
