"""The renderer's recording mode: radiance as a polynomial in the materials, recorded once and
evaluated at any albedos and glossy reflectance, against the path tracer itself."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from grassd.sim.albedo_terms import MONOMIALS, N_MONOMIALS, code_table, monomial_values
from grassd.sim.errors import SceneError
from grassd.sim.geometry import build_scene
from grassd.sim.light_input import LightInput
from grassd.sim.scene import DisplaySpec, PixelSpec, RenderSettings, Viewpoint

LENGTHS = np.array([0.0, 6.0, 12.0, 20.0])
VIEW = Viewpoint(150.0, 1.2, 30.0)
PINK = dict(yellow_srgb=(225.0, 200.0, 205.0), green_srgb=(235.0, 140.0, 185.0),
            base_srgb=(215.0, 185.0, 195.0))


@pytest.fixture(scope="module")
def sunny(shared_hdri):
    return LightInput(shared_hdri("courtyard"), 5000.0, sun_lux=30000.0, sun_azimuth_deg=120.0,
                      sun_elevation_deg=35.0).lighting()


def _albedo(pixel: PixelSpec) -> np.ndarray:
    return build_scene(DisplaySpec(pixel), LENGTHS).albedo.astype(np.float64)


def _agree_path_for_path(a: np.ndarray, b: np.ndarray, rounding: float = 1e-6) -> None:
    """The same paths give the same radiance: equal to float rounding (``rounding``, relative,
    for the median replicate mean), except where one of the rare paths that graze an edge
    takes another turn in the other kernel (its rounding differs), which moves a replicate
    mean by at most a few 1e-3."""
    rel = np.abs(a - b) / np.abs(b)
    assert np.median(rel) < rounding, np.median(rel)
    assert rel.max() < 5e-3, rel.max()


def test_monomials_are_every_product_of_at_most_three_symbols():
    assert N_MONOMIALS == 56 and MONOMIALS.sum(axis=1).max() == 3
    table = code_table()
    assert sorted(table[table >= 0]) == list(range(56))
    values = monomial_values(np.full((4, 3), 0.5), 0.2)  # diffuse symbols 0.4, glossy 0.2
    k = int(np.flatnonzero((MONOMIALS == [1, 0, 0, 0, 2]).all(axis=1))[0])
    assert values[k] == pytest.approx(0.4 * 0.2 * 0.2)


@pytest.mark.parametrize("splay", [0.0, 8.0])
def test_terms_give_the_tracers_radiance_at_the_reference_and_at_other_albedos(renderer, sunny,
                                                                              splay):
    """Lambertian paths do not depend on the albedos, so terms recorded with the default
    pixel give, at the pink pixel's albedos, what tracing the pink pixel gives."""
    settings = RenderSettings(samples=1024, replicates=4, seed=5)
    ref = PixelSpec(splay_deg=splay)
    terms = renderer.albedo_terms(DisplaySpec(ref), sunny, VIEW, LENGTHS, settings)
    assert terms.coefficients.shape == (4, len(LENGTHS), 56, 3)
    own = renderer.characteristic(DisplaySpec(ref), sunny, VIEW, LENGTHS, settings)
    _agree_path_for_path(terms.radiance(_albedo(ref)), own.rgb_replicates)
    pink = replace(ref, **PINK)
    other = renderer.characteristic(DisplaySpec(pink), sunny, VIEW, LENGTHS, settings)
    _agree_path_for_path(terms.radiance(_albedo(pink)), other.rgb_replicates)


def test_glossy_terms_predict_another_gloss_within_the_monte_carlo_error(renderer, sunny):
    """Glossy paths are sampled with the reference's lobe, so another ``ks`` or albedo takes
    other paths when traced: the recorded estimate agrees within its standard error."""
    settings = RenderSettings(samples=4096, replicates=8, seed=9)
    ref = PixelSpec(specular=0.05, smoothness=0.7)
    terms = renderer.albedo_terms(DisplaySpec(ref), sunny, VIEW, LENGTHS, settings, glossy=True)
    # A sharp lobe (smoothness 0.7: cos^245) magnifies float rounding of the mirror direction
    # a thousandfold in the sun's glints.
    _agree_path_for_path(terms.radiance(_albedo(ref), 0.05),
                         renderer.characteristic(DisplaySpec(ref), sunny, VIEW, LENGTHS,
                                                 settings).rgb_replicates, rounding=1e-3)
    target = replace(ref, specular=0.2, **PINK)
    traced = renderer.characteristic(DisplaySpec(target), sunny, VIEW, LENGTHS,
                                     replace(settings, seed=10))
    reps = terms.radiance(_albedo(target), 0.2)
    se = np.hypot(reps.std(axis=0, ddof=1) / np.sqrt(len(reps)), traced.rgb_stderr)
    z = (reps.mean(axis=0) - traced.rgb_linear) / se
    assert np.abs(z).max() < 4.5, z
    assert np.abs(reps.mean(axis=0) / traced.rgb_linear - 1).max() < 0.05


def test_lambertian_terms_refuse_a_specular_evaluation(renderer, sunny):
    terms = renderer.albedo_terms(DisplaySpec(PixelSpec()), sunny, VIEW, LENGTHS[:1],
                                  RenderSettings(samples=64, replicates=2))
    with pytest.raises(SceneError, match="without the glossy lobe"):
        terms.radiance(_albedo(PixelSpec()), 0.1)


def test_recording_refuses_more_bounces_than_the_polynomial_holds(renderer, sunny):
    with pytest.raises(SceneError, match="max_bounces <= 3"):
        renderer.albedo_terms(DisplaySpec(PixelSpec()), sunny, VIEW, LENGTHS,
                              RenderSettings(samples=64, replicates=2, max_bounces=4))
