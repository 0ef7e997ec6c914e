"""Spectra for the camera's own RGB: smooth reflectances of Rec.709 albedos (Jakob-Hanika),
the light's basis, the transfer of the albedo polynomial, and a photo's development."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from grassd.calib.camera_response import (
    CameraSensitivities,
    cie_observer,
    illuminant,
    integrate,
    recover_reflectance,
)
from grassd.calib.colour_spaces import M_REC709_TO_XYZ, M_XYZ_TO_REC709, luminance
from grassd.calib.spectral_prediction import (
    EDGE,
    Development,
    emitter_spectra,
    fitted_light_basis,
    light_basis,
    rec709_weights,
    sigmoid_coefficients,
    sigmoid_spectra,
    transfer,
)
from grassd.sim.albedo_terms import monomial_values, monomials_of

#: Albedos (linear Rec.709) of grasses, soils, a pale pink, a black and a white.
ALBEDOS = np.array([[0.58, 0.47, 0.08], [0.19, 0.35, 0.05], [0.10, 0.06, 0.03],
                    [0.79, 0.30, 0.42], [0.005, 0.005, 0.005], [0.95, 0.95, 0.95]])


def _rec709(spectra: np.ndarray) -> np.ndarray:
    return spectra @ rec709_weights().T


def test_smooth_spectra_have_their_albedo_and_stay_within_0_and_1():
    spectra = sigmoid_spectra(ALBEDOS)
    assert spectra.shape == (len(ALBEDOS), rec709_weights().shape[1])
    np.testing.assert_allclose(_rec709(spectra), ALBEDOS, atol=1e-9)
    assert spectra.min() > 0.0 and spectra.max() < 1.0
    # the corners of the albedo cube too (held EDGE inside it)
    corners = np.array(list(itertools.product([0.0, 1.0], repeat=3)))
    np.testing.assert_allclose(_rec709(sigmoid_spectra(corners)),
                               np.clip(corners, EDGE, 1 - EDGE), atol=1e-9)


def test_smooth_spectra_are_colour_sciences_jakob_hanika():
    ours = sigmoid_spectra(ALBEDOS[:4])
    theirs = recover_reflectance(ALBEDOS[:4] @ M_REC709_TO_XYZ.T)
    # the same family of spectra and the same colour: the same spectrum, up to colour's
    # CIELAB tolerance
    assert np.abs(ours - theirs).max() < 3e-3


def test_a_grey_is_flat_and_the_solve_keeps_shapes():
    c = sigmoid_coefficients(np.full((2, 2, 3), 0.3))
    assert c.shape == (2, 2, 3)
    np.testing.assert_allclose(c[..., :2], 0.0, atol=1e-12)
    np.testing.assert_allclose(sigmoid_spectra([0.3, 0.3, 0.3]), 0.3, atol=1e-9)


def _readout(b: np.ndarray) -> np.ndarray:
    """(3, 3) the CIE observer's Rec.709 of each column of a light basis."""
    return M_XYZ_TO_REC709 @ integrate(b.T, cie_observer()).T


def test_the_default_light_basis_reads_as_its_primaries_and_white_is_d65():
    b = light_basis()
    np.testing.assert_allclose(_readout(b), np.eye(3), atol=1e-9)
    d65 = illuminant("D65")
    white = b @ np.ones(3)
    np.testing.assert_allclose(white / white.max(), d65 / d65.max(), atol=0.02)


def test_an_emitters_spectrum_is_smooth_and_has_its_colour():
    rgb = np.array([[2.0, 1.6, 1.1], [0.2, 0.5, 0.9], [0.0, 0.0, 0.0]])
    e = emitter_spectra(rgb)
    np.testing.assert_allclose(_readout(e.T), rgb.T, rtol=2e-3, atol=1e-12)
    assert (e >= 0).all() and not e[2].any()


def test_a_fitted_basis_gives_the_white_card_its_texels_spectrum():
    rng = np.random.default_rng(3)
    texels = np.vstack([rng.uniform(0.1, 1.0, (300, 3)) * [1.0, 0.8, 0.5],  # warm lamps
                        rng.uniform(0.1, 1.0, (300, 3)) * [0.5, 0.7, 1.0]])  # bluish windows
    weights = rng.uniform(0.0, 1.0, len(texels))
    b = fitted_light_basis(texels, weights)
    np.testing.assert_allclose(_readout(b), np.eye(3), atol=1e-9)
    card = weights @ emitter_spectra(texels)
    np.testing.assert_allclose(b @ (weights @ texels), card, rtol=1e-9, atol=1e-12 * card.max())
    # and each texel's own spectrum closer than the default basis gives it
    own = emitter_spectra(texels)
    fitted_err = np.linalg.norm(texels @ b.T - own, axis=1) @ weights
    default_err = np.linalg.norm(texels @ light_basis().T - own, axis=1) @ weights
    print(f"texel spectra error: fitted {fitted_err:.4g}, default {default_err:.4g}")
    assert fitted_err < 0.5 * default_err


def test_grey_materials_transfer_as_rgb_transport_under_the_observer():
    """Flat spectra reflect each basis spectrum unchanged: the CIE observer then reads every
    monomial exactly as the RGB transport evaluates it."""
    albedo = np.array([[0.4] * 3, [0.2] * 3, [0.1] * 3, [0.02] * 3])
    rng = np.random.default_rng(5)
    tinted = fitted_light_basis(rng.uniform(0.2, 1.0, (50, 3)), rng.uniform(0.5, 1.0, 50))
    for basis in (light_basis(), tinted):
        t = transfer(monomial_values(sigmoid_spectra(albedo), 0.1, 5), cie_observer(),
                     basis)  # (M, 3, 3) XYZ
        rgb = t @ M_XYZ_TO_REC709.T  # (M, k, c)
        mono = monomial_values(albedo, 0.1, 5)  # (M, 3)
        expected = np.einsum("mc,kc->mkc", mono, np.eye(3))
        np.testing.assert_allclose(rgb, expected, atol=1e-9 * mono.max())


def test_coloured_materials_differ_from_rgb_transport_beyond_one_bounce():
    """One reflection of white light keeps the albedo's Rec.709 exactly; a product of two
    coloured reflectances is not the product of their Rec.709, so spectral transport differs
    from RGB where light meets two coloured surfaces."""
    albedo = np.array([[0.58, 0.47, 0.08], [0.19, 0.35, 0.05], [0.10, 0.06, 0.03],
                       [0.02] * 3])
    t = transfer(monomial_values(sigmoid_spectra(albedo), 0.0, 2), cie_observer())
    white = np.einsum("mkc,dc->md", t, M_XYZ_TO_REC709)  # white light (1, 1, 1), Rec.709
    mono = monomial_values(albedo, 0.0, 2)
    rows = monomials_of(2)
    single = np.flatnonzero((rows.sum(axis=1) == 1) & (rows[:, 4] == 0))
    np.testing.assert_allclose(white[single], mono[single], atol=2e-9)  # the solve
    green_twice = np.flatnonzero(rows[:, 1] == 2)
    assert np.abs(white[green_twice] / mono[green_twice] - 1.0).max() > 0.01


def test_the_development_puts_the_grey_at_its_exposure():
    nikon = CameraSensitivities.from_colour("nikon-d5100")
    dev = Development.of_profile(nikon.values, [2.1, 1.0, 1.6], nikon.xyz_to_camera, 0.19)
    white_raw = integrate(light_basis() @ np.ones(3), nikon.values)
    k = dev.exposure(white_raw)
    grey = dev.develop(white_raw * 0.19) * k
    assert float(luminance(grey)) == pytest.approx(0.18, rel=1e-12)
