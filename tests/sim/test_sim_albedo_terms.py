"""The renderer's recording mode: radiance as a polynomial in the materials, recorded once and
evaluated at any albedos and glossy reflectance, against the path tracer itself."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from grassd.sim.albedo_terms import (
    MONOMIALS,
    N_MONOMIALS,
    TERM_DEGREE,
    code_table,
    monomial_values,
    monomials,
    n_monomials,
    symbol_values,
)
from grassd.sim.errors import SceneError
from grassd.sim.geometry import build_scene
from grassd.sim.light_input import LightInput
from grassd.sim.scene import MAX_BOUNCES, DisplaySpec, PixelSpec, RenderSettings, Viewpoint

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
    pixel give, at the pink pixel's albedos, what tracing the pink pixel gives (up to 3
    bounces: the shallow recording has no tail term)."""
    settings = RenderSettings(samples=1024, replicates=4, seed=5, max_bounces=3)
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


def test_monomials_of_a_higher_degree_extend_those_of_degree_three():
    deep = monomials(TERM_DEGREE)
    assert n_monomials(TERM_DEGREE) == len(deep) == 1287 and deep.sum(axis=1).max() == 8
    np.testing.assert_array_equal(deep[:N_MONOMIALS], MONOMIALS)
    table = code_table(TERM_DEGREE)
    assert sorted(table[table >= 0]) == list(range(len(deep)))
    assert table[deep @ (16 ** np.arange(5))].tolist() == list(range(len(deep)))
    rng = np.random.default_rng(1)
    albedo = rng.random((2, 4, 3))
    values = monomial_values(albedo, 0.1, TERM_DEGREE)
    direct = (symbol_values(albedo, 0.1)[:, None] ** deep[None, :, :, None]).prod(axis=-2)
    np.testing.assert_allclose(values, direct, rtol=1e-12)
    np.testing.assert_allclose(values[:, :N_MONOMIALS], monomial_values(albedo, 0.1))


def test_deep_terms_give_the_tracers_radiance_at_every_depth(renderer, sunny):
    """Paths that Russian roulette alone ends: at the reference the polynomial with its tail
    term is the tracer's radiance path for path; with no vertex beyond its degree (at most 6
    bounces, degree 8) it is so at other albedos too."""
    ref = PixelSpec()
    pink = replace(ref, **PINK)
    deep = RenderSettings(samples=1024, replicates=4, seed=5, max_bounces=MAX_BOUNCES)
    terms = renderer.albedo_terms(DisplaySpec(ref), sunny, VIEW, LENGTHS, deep)
    assert (terms.degree, terms.tail) == (TERM_DEGREE, True)
    assert terms.coefficients.shape == (4, len(LENGTHS), 1287, 3)
    own = renderer.characteristic(DisplaySpec(ref), sunny, VIEW, LENGTHS, deep)
    _agree_path_for_path(terms.radiance(_albedo(ref)), own.rgb_replicates)
    six = replace(deep, max_bounces=6)
    terms = renderer.albedo_terms(DisplaySpec(ref), sunny, VIEW, LENGTHS, six)
    assert (terms.degree, terms.tail) == (6, False)
    _agree_path_for_path(terms.radiance(_albedo(pink)),
                         renderer.characteristic(DisplaySpec(pink), sunny, VIEW, LENGTHS,
                                                 six).rgb_replicates)


def test_deep_terms_at_other_materials_agree_with_a_deep_render(renderer, sunny):
    """Terms recorded with the default pixel, evaluated at the pink one (whose light goes
    deepest), against tracing the pink pixel without a cut: for the same paths only the tail's
    vertices differ (they keep the reference's reflectance), well within 1 % here; with other
    paths, within the Monte Carlo error."""
    ref = PixelSpec()
    pink = replace(ref, **PINK)
    deep = RenderSettings(samples=1024, replicates=8, seed=11, max_bounces=MAX_BOUNCES)
    terms = renderer.albedo_terms(DisplaySpec(ref), sunny, VIEW, LENGTHS, deep)
    reps = terms.radiance(_albedo(pink))
    same = renderer.characteristic(DisplaySpec(pink), sunny, VIEW, LENGTHS, deep)
    assert np.abs(reps.mean(axis=0) / same.rgb_linear - 1).max() < 0.01
    other = renderer.characteristic(DisplaySpec(pink), sunny, VIEW, LENGTHS,
                                    replace(deep, seed=12))
    se = np.hypot(reps.std(axis=0, ddof=1) / np.sqrt(len(reps)), other.rgb_stderr)
    z = (reps.mean(axis=0) - other.rgb_linear) / se
    assert np.abs(z).max() < 4.5, z
    shallow = renderer.characteristic(DisplaySpec(pink), sunny, VIEW, LENGTHS,
                                      replace(deep, max_bounces=3))
    assert np.all(shallow.rgb_linear < same.rgb_linear)  # the cut at 3 loses light


def test_deep_glossy_terms_predict_another_gloss_within_the_monte_carlo_error(renderer,
                                                                             sunny):
    """A glossy path keeps both lobes while its terms fit, then picks one per term at random:
    still an unbiased estimate of another ``ks`` and albedos."""
    settings = RenderSettings(samples=1024, replicates=8, seed=9, max_bounces=MAX_BOUNCES)
    ref = PixelSpec(specular=0.05, smoothness=0.5)
    terms = renderer.albedo_terms(DisplaySpec(ref), sunny, VIEW, LENGTHS, settings, glossy=True)
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


def test_recording_refuses_a_degree_its_codes_cannot_hold(renderer, sunny):
    with pytest.raises(SceneError, match="degree must be in 1..15"):
        renderer.albedo_terms(DisplaySpec(PixelSpec()), sunny, VIEW, LENGTHS,
                              RenderSettings(samples=64, replicates=2, max_bounces=20),
                              degree=16)
