"""Colour corrections chosen by their leave-one-out error on the checker's patches."""

from __future__ import annotations

import numpy as np
import pytest

from grassd.calib.ccm import (
    CCM_FORMS,
    ColourCorrection,
    compare_ccm_forms,
    fit_ccm,
    leave_one_out_de00,
    leave_one_out_rgb,
    residual_de00,
    select_ccm,
)
from grassd.calib.charts import colorchecker_classic, spyder_checkr_24
from grassd.calib.errors import ShapeError, UnknownMethodError

M_TRUE = np.array([[0.92, 0.10, 0.02], [0.04, 1.03, -0.05], [0.01, 0.07, 0.88]])


def _refit_loo(virtual, real, method, degree):
    """Leave-one-out by brute force: 24 refits with the patch left out."""
    out = np.empty_like(real)
    for i in range(len(real)):
        keep = np.arange(len(real)) != i
        fit = fit_ccm(virtual[keep], real[keep], method, degree=degree)
        out[i] = fit.apply(virtual[i:i + 1])[0]
    return out


@pytest.mark.parametrize("form", list(CCM_FORMS))
def test_closed_form_leave_one_out_equals_refitting(form):
    method, degree = CCM_FORMS[form]
    real = colorchecker_classic().prophoto()
    rng = np.random.default_rng(3)
    virtual = (real @ np.linalg.inv(M_TRUE).T) * (1 + 0.02 * rng.standard_normal(real.shape))
    np.testing.assert_allclose(leave_one_out_rgb(virtual, real, method, degree=degree),
                               _refit_loo(virtual, real, method, degree), rtol=1e-7, atol=1e-10)


def test_leave_one_out_exceeds_the_fitting_residual_and_is_reported():
    real = spyder_checkr_24().prophoto()
    rng = np.random.default_rng(5)
    virtual = (real @ np.linalg.inv(M_TRUE).T) * (1 + 0.02 * rng.standard_normal(real.shape))
    for form, fit in compare_ccm_forms(virtual, real).items():
        assert fit.loo_de00 is not None and fit.loo_de00.shape == (24,)
        assert fit.loo_mean_de00 > fit.mean_de00, form
        assert fit.reported_de00 == (fit.loo_mean_de00, fit.loo_max_de00)
        print(f"{form}: fit {fit.mean_de00:.3f}/{fit.max_de00:.3f} "
              f"loo {fit.loo_mean_de00:.3f}/{fit.loo_max_de00:.3f} dE00")
    # with 13 terms per channel fitted to 24 noisy patches the gap is widest
    fits = compare_ccm_forms(virtual, real)
    gap = {f: c.loo_mean_de00 / c.mean_de00 for f, c in fits.items()}
    assert gap["root-polynomial-3"] > gap["3x3"]
    # on a linear mismatch with noise the 3x3 generalises best and is chosen
    assert select_ccm(virtual, real).form == "3x3"


def test_a_nonlinear_camera_gets_a_root_polynomial():
    real = colorchecker_classic().prophoto()
    virtual = real**1.15 * real.sum(axis=1, keepdims=True) ** -0.15  # homogeneous distortion
    best = fit_ccm(virtual, real, "auto")
    assert best.method == "root-polynomial"
    assert [s.form for s in best.candidates][0] == best.form
    assert {s.form for s in best.candidates} == set(CCM_FORMS)
    means = [s.loo_mean_de00 for s in best.candidates]
    assert means == sorted(means) and best.loo_mean_de00 == means[0]
    assert best.loo_mean_de00 < fit_ccm(virtual, real).loo_mean_de00
    # the chosen correction is applied as any other: its fitting residual is reproduced
    assert residual_de00(np.clip(best.apply(virtual), 0, None), real).mean() == pytest.approx(
        best.mean_de00)


def test_too_few_patches_for_leave_one_out():
    real = colorchecker_classic().prophoto()
    virtual = real @ np.linalg.inv(M_TRUE).T
    # 13 patches determine a degree-3 fit exactly: nothing is left to predict a patch from
    loo = leave_one_out_de00(virtual[:13], real[:13], "root-polynomial", degree=3)
    assert np.isinf(loo).any()
    # select_ccm drops the forms the patches cannot test
    assert {s.form for s in select_ccm(virtual[:10], real[:10]).candidates} == {
        "3x3", "root-polynomial-2"}
    with pytest.raises(ShapeError, match="at least 4 patches"):
        select_ccm(virtual[:3], real[:3])
    with pytest.raises(UnknownMethodError, match="root-polynomial-2"):
        select_ccm(virtual, real, forms=("cubic",))


def test_a_matrix_read_back_keeps_its_old_form():
    m = np.eye(3)
    old = ColourCorrection("3x3", m, 1, np.zeros(0), float("nan"), float("nan"))
    assert old.loo_de00 is None and old.form == "3x3" and old.candidates == ()
    assert all(np.isnan(old.reported_de00))


@pytest.mark.parametrize("form", list(CCM_FORMS))
def test_a_scaled_correction_applies_to_scaled_input(form):
    method, degree = CCM_FORMS[form]
    real = colorchecker_classic().prophoto()
    virtual = real**1.1 * real.sum(axis=1, keepdims=True) ** -0.1
    fit = fit_ccm(virtual, real, method, degree=degree)
    np.testing.assert_allclose(fit.scaled(3.5).apply(virtual[:6]), fit.apply(3.5 * virtual[:6]),
                               rtol=1e-10)
    assert fit.scaled(2.0).loo_mean_de00 == fit.loo_mean_de00


def test_ogcd_takes_a_chosen_root_polynomial_correction():
    from grassd.calib.ogcd import ogcd_from_rgb

    real = colorchecker_classic().prophoto()
    virtual = real**1.15 * real.sum(axis=1, keepdims=True) ** -0.15
    best = select_ccm(virtual, real)
    assert best.method == "root-polynomial"
    sweep = virtual[[18, 19, 20, 3, 11]]  # a few patches as a curve, first one the reference
    res = ogcd_from_rgb(sweep, space="prophoto", ccm=best.scaled(0.5))
    plain = ogcd_from_rgb(best.apply(0.5 * sweep), space="prophoto")
    np.testing.assert_allclose(res.ogcd, plain.ogcd, rtol=1e-9, atol=1e-9)
