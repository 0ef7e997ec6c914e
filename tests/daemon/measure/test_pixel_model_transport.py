"""The measure's pixel models read their terms with the characteristic's transport
(:class:`grassd.daemon.measure.pixel_model.PixelColourModel`): spectrally, the gains scale the
materials' reflectance spectra and the observer reads the products of spectra; where spectra
and Rec.709 agree (flat reflectances) the two readings are the same at any gain."""

from __future__ import annotations

import math

import numpy as np
import pytest

from grassd.calib.camera_response import cie_observer, integrate
from grassd.calib.colour_spaces import M_XYZ_TO_REC709
from grassd.calib.spectral_prediction import rec709_weights, sigmoid_spectra
from grassd.daemon.core.calibration.transport import SpectralTransport
from grassd.daemon.core.calibration.variation import DisplayVariation
from grassd.daemon.measure.pixel_model import PixelColourModel
from grassd.sim.albedo_terms import monomials, n_monomials
from grassd.sim.lighting import build_lighting
from grassd.sim.scene import DisplaySpec, PixelSpec

WHITE_SKY = build_lighting(np.ones((32, 64, 3), np.float32), ambient_lux=math.pi)
AMBER_SKY = build_lighting(np.ones((32, 64, 3), np.float32)
                           * np.array([1.0, 0.8, 0.5], np.float32), ambient_lux=800.0)
GREY = PixelSpec(yellow_srgb=(150.0, 150.0, 150.0), green_srgb=(110.0, 110.0, 110.0),
                 base_srgb=(90.0, 90.0, 90.0), cavity_srgb=(40.0, 40.0, 40.0))
CYAN = PixelSpec(yellow_srgb=(200.0, 220.0, 120.0), green_srgb=(40.0, 170.0, 190.0),
                 base_srgb=(90.0, 120.0, 130.0))
GRID = np.array([0.0, 10.0, 20.0])


def _models(pixel: PixelSpec, lighting, coefficients: np.ndarray
            ) -> tuple[PixelColourModel, PixelColourModel]:
    """The same terms read with Rec.709 and with spectral transport."""
    display = DisplaySpec(pixel)
    rgb = PixelColourModel(GRID, coefficients, np.ones(3), display.pixel.albedo_linear)
    spectral = PixelColourModel(GRID, coefficients, np.ones(3), display.pixel.albedo_linear,
                                transport=SpectralTransport.of(display, lighting, 16))
    return rgb, spectral


@pytest.mark.parametrize("gain", [0.6, 1.0, 1.3])
def test_flat_reflectances_read_the_same_with_either_transport(gain):
    """Grey materials have flat spectra, and the light's basis is read by the observer as the
    unit primaries, so any product of them, at any gain, reads as the product of the Rec.709
    albedos, even under coloured light."""
    rng = np.random.default_rng(3)
    coefficients = rng.uniform(0.0, 1.0, (2, len(GRID), n_monomials(3), 3))
    rgb, spectral = _models(GREY, AMBER_SKY, coefficients)
    varied = DisplayVariation(np.array([0.0, 0.4]), np.full(2, gain), np.full(2, 1.0 / gain))
    a, b = rgb.grid_radiance(varied), spectral.grid_radiance(varied)
    np.testing.assert_allclose(b, a, rtol=2e-3, atol=1e-6)


def test_a_gain_scales_the_spectrum_before_the_product():
    """A unit term of green^2 in white light reads, with the green gain g, as the observer's
    Rec.709 of (g rho_green)^2: the square of a spectrum, not of its Rec.709 reading, so it
    differs from Rec.709 transport for a saturated green."""
    codes = [tuple(m) for m in monomials(3)]
    coefficients = np.zeros((1, len(GRID), n_monomials(3), 3))
    coefficients[0, :, codes.index((0, 2, 0, 0, 0))] = 1.0  # every light channel: white
    rgb, spectral = _models(CYAN, WHITE_SKY, coefficients)
    g = 0.8
    varied = DisplayVariation(np.zeros(1), np.full(1, g), np.ones(1))
    rho = sigmoid_spectra(CYAN.albedo_linear)[1]
    expected = rec709_weights() @ (g * rho) ** 2
    np.testing.assert_allclose(spectral.grid_radiance(varied)[0, 0], expected, atol=2e-4)
    np.testing.assert_allclose(rgb.grid_radiance(varied)[0, 0],
                               (g * CYAN.albedo_linear[1]) ** 2, atol=1e-9)
    assert np.max(np.abs(expected - (g * CYAN.albedo_linear[1]) ** 2)) > 0.005


def test_a_term_of_one_light_channel_reads_that_channels_spectrum():
    """A unit term of green in the light's red channel reads as the observer's Rec.709 of
    rho_green times the red channel's spectrum (light channel in, observer channel out), not
    the green's red albedo alone."""
    codes = [tuple(m) for m in monomials(3)]
    coefficients = np.zeros((1, len(GRID), n_monomials(3), 3))
    coefficients[0, :, codes.index((0, 1, 0, 0, 0)), 0] = 1.0
    _, spectral = _models(CYAN, AMBER_SKY, coefficients)
    rho = sigmoid_spectra(CYAN.albedo_linear)[1]
    red = spectral.transport.basis[:, 0]
    expected = M_XYZ_TO_REC709 @ integrate(rho * red, cie_observer())
    got = spectral.grid_radiance(DisplayVariation.none(1))[0, 0]
    np.testing.assert_allclose(got, expected, atol=1e-9)
    rec709 = np.array([CYAN.albedo_linear[1, 0], 0.0, 0.0])  # Rec.709 transport's reading
    assert np.max(np.abs(got - rec709)) > 0.005
