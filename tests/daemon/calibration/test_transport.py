"""Spectral transport of the simulated characteristic
(:mod:`grassd.daemon.core.calibration.transport`): where spectra and Rec.709 agree it adds
nothing, where they do not it moves the colour as the materials' spectra say, it is an unbiased
estimate whatever share of the paths it records, and the configuration chooses it."""

from __future__ import annotations

import math

import numpy as np
import pytest
from colour import delta_E

from grassd.calib.colour_spaces import prophoto_to_lab, rec709_to_prophoto
from grassd.calib.spectral_prediction import rec709_weights, sigmoid_spectra
from grassd.daemon.core.calibration.simulation import simulate_curve, white_radiance
from grassd.daemon.core.calibration.transport import SpectralTransport, light_spectra_basis
from grassd.sim.albedo_terms import monomials
from grassd.sim.lighting import build_lighting
from grassd.sim.scene import DisplaySpec, PixelSpec, RenderSettings, Viewpoint

WHITE_SKY = build_lighting(np.ones((32, 64, 3), np.float32), ambient_lux=math.pi)
GREY = PixelSpec(yellow_srgb=(150.0, 150.0, 150.0), green_srgb=(110.0, 110.0, 110.0),
                 base_srgb=(90.0, 90.0, 90.0), cavity_srgb=(40.0, 40.0, 40.0))
CYAN = PixelSpec(yellow_srgb=(200.0, 220.0, 120.0), green_srgb=(40.0, 170.0, 190.0),
                 base_srgb=(90.0, 120.0, 130.0))
LENGTHS = np.array([0.0, 10.0, 20.0])


def _lab(rgb: np.ndarray, white: np.ndarray) -> np.ndarray:
    return prophoto_to_lab(rec709_to_prophoto(np.clip(rgb / white, 0.0, None)))


def test_a_monomial_reads_as_the_product_of_its_spectra():
    """Under white light (the basis's three spectra summed: D65), a unit coefficient of the
    monomial green^2 * base gives the observer's Rec.709 of rho_green(l)^2 rho_base(l), not the
    product of the albedos' Rec.709; a single material's monomial gives its albedo exactly."""
    t = SpectralTransport.of(DisplaySpec(CYAN), WHITE_SKY, 16)
    rgb, spectral = t.matrices(3)
    codes = [tuple(m) for m in monomials(3)]
    rho = sigmoid_spectra(CYAN.albedo_linear)
    white = spectral.sum(axis=1)  # (M, 3): the light's channels in white light's proportions
    k = codes.index((0, 2, 1, 0, 0))
    np.testing.assert_allclose(white[k], rec709_weights() @ (rho[1] ** 2 * rho[2]), atol=2e-4)
    assert np.max(np.abs(white[k] - rgb[k])) > 0.01  # the two transports differ here
    single = codes.index((0, 1, 0, 0, 0))
    np.testing.assert_allclose(white[single], CYAN.albedo_linear[1], atol=2e-4)


def test_a_grey_pixel_under_a_white_sky_gains_nothing(renderer):
    """Flat reflectances under white light: every product of spectra reads as the product of
    the Rec.709 values, so the difference is zero at every length (to float rounding)."""
    display = DisplaySpec(GREY)
    t = SpectralTransport.of(display, WHITE_SKY, 4)
    settings = RenderSettings(samples=256, replicates=2, seed=1)
    diff, _ = t.difference(renderer, display, WHITE_SKY, Viewpoint(170, 2, 0), LENGTHS,
                           settings)
    assert diff.shape == (2, 3, 3)
    assert np.max(np.abs(diff)) < 1e-4 * float(white_radiance(WHITE_SKY).max())


def test_any_share_estimates_the_same_spectral_colour(renderer):
    """The difference is recorded on 1 in ``share`` of the trace's paths; recording them all
    and recording 1 in 16 estimate the same colour, within their standard errors, and both
    move the saturated pixel away from Rec.709 transport by more than those errors."""
    display = DisplaySpec(CYAN)
    lighting = build_lighting(np.ones((32, 64, 3), np.float32) * np.array([1.0, 0.9, 0.7],
                                                                          np.float32),
                              ambient_lux=500.0)
    vp = Viewpoint(140, 1.5, 45)
    settings = RenderSettings(samples=1024, replicates=8, seed=4)
    curves = {share: simulate_curve(renderer, display, lighting, vp, LENGTHS, settings,
                                    spectral=SpectralTransport.of(display, lighting, share))
              for share in (1, 16)}
    rgb = simulate_curve(renderer, display, lighting, vp, LENGTHS, settings)
    a, b = curves[1], curves[16]
    se = np.hypot(a.rgb_stderr, b.rgb_stderr)
    assert np.all(np.abs(a.rgb_linear - b.rgb_linear) <= 4 * se + 1e-9)
    white = white_radiance(lighting)
    moved = delta_E(_lab(b.rgb_linear, white), _lab(rgb.rgb_linear, white))
    assert moved[-1] > 0.5, moved
    assert b.seconds["spectral"] > 0 and rgb.seconds["spectral"] == 0


def test_the_basis_gives_the_white_card_what_rec709_gives_it():
    """The light's basis is read by the observer as the unit primaries, so the white card,
    and with it the normalisation, is the same under either transport."""
    lighting = build_lighting(np.ones((32, 64, 3), np.float32) * np.array([1.0, 0.8, 0.5],
                                                                          np.float32),
                              ambient_lux=1000.0)
    from grassd.calib.camera_response import cie_observer, integrate
    from grassd.calib.colour_spaces import M_XYZ_TO_REC709

    basis = light_spectra_basis(lighting)
    readout = M_XYZ_TO_REC709 @ integrate(basis.T, cie_observer()).T
    np.testing.assert_allclose(readout, np.eye(3), atol=1e-6)


def _config(simulation: str = ""):
    """The embedded default configuration with ``simulation`` added to its [simulation]."""
    from grassd.daemon.core.config.settings import default_config_text, parse_config

    text = default_config_text().replace("[simulation]\n", f"[simulation]\n{simulation}", 1)
    return parse_config(text, source="t.toml")


@pytest.mark.parametrize("value", ["spectral", "rgb"])
def test_the_configuration_chooses_the_transport(value):
    from grassd.daemon.core.calibration.calibrate import Calibrator

    default = _config().simulation
    assert (default.transport, default.spectral_share) == ("spectral", 16)
    cfg = _config(f'transport = "{value}"\nspectral_share = 8\n')
    t = Calibrator(cfg).transport(DisplaySpec(CYAN), WHITE_SKY)
    assert (t is None) == (value == "rgb")
    assert t is None or t.share == 8


def test_an_unknown_transport_is_refused_naming_the_choices():
    from grassd.daemon.core.errors import ConfigError

    with pytest.raises(ConfigError, match="spectral") as err:
        _config('transport = "hero"\n')
    assert "transport" in str(err.value)
