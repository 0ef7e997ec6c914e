"""Reference charts and colour-correction fits (3x3 and root-polynomial)."""

from __future__ import annotations

import numpy as np
import pytest
from colour import delta_E

from grassd.calib.ccm import compare_ccm_methods, fit_ccm, residual_de00
from grassd.calib.charts import colorchecker_classic, get_chart, load_chart, spyder_checkr_24
from grassd.calib.colour_spaces import prophoto_to_lab
from grassd.calib.errors import ChartError, NonFiniteError, ShapeError, UnknownMethodError

# A plausible "virtual -> real" mismatch: renderer and camera disagree on white and saturation.
M_TRUE = np.array([[0.92, 0.10, 0.02], [0.04, 1.03, -0.05], [0.01, 0.07, 0.88]])


def _synthetic(noise: float, seed: int = 11):
    real = spyder_checkr_24().prophoto()
    virtual = real @ np.linalg.inv(M_TRUE).T
    rng = np.random.default_rng(seed)
    virtual_noisy = virtual * (1.0 + noise * rng.standard_normal(virtual.shape))
    return virtual, virtual_noisy, real


def test_charts_have_24_d50_patches_and_sane_greys():
    for chart in (colorchecker_classic(), spyder_checkr_24()):
        assert chart.lab.shape == (24, 3) and len(chart.patch_names) == 24
        pp = chart.prophoto()
        assert (pp > 0).all() and (pp < 1).all()
        g = chart.grey_index()
        assert abs(chart.lab[g, 0] - 50) < 2 and np.hypot(*chart.lab[g, 1:]) < 3
    cc = colorchecker_classic()
    # colour-science xyY -> our D50 Lab reproduces X-Rite's published 2014 Lab (dark skin, white)
    np.testing.assert_allclose(cc.lab[0], [37.54, 14.37, 14.92], atol=0.02)
    np.testing.assert_allclose(cc.lab[18], [95.19, -1.03, 2.93], atol=0.02)
    sp = spyder_checkr_24()
    assert sp.patch_names[18] == "A1" and sp.lab[18, 0] == pytest.approx(96.04)


def test_chart_from_file_and_errors(tmp_path):
    ref = spyder_checkr_24()
    path = tmp_path / "calib_chart.csv"
    lines = ["# my chart, D50", "name,L,a,b"]
    lines += [
        f"{n},{lab[0]},{lab[1]},{lab[2]}" for n, lab in zip(ref.patch_names, ref.lab, strict=True)
    ]
    path.write_text("\n".join(lines) + "\n")
    chart = get_chart(path)
    np.testing.assert_allclose(chart.lab, ref.lab)
    assert chart.patch_names == ref.patch_names
    assert get_chart("SpyderCheckr 24").name.startswith("Datacolor")
    bad = tmp_path / "short.csv"
    bad.write_text("\n".join(lines[:10]))
    with pytest.raises(ChartError, match="24 patches"):
        load_chart(bad)
    bad.write_text("\n".join(lines[:5] + ["x,abc,1,2"]))
    with pytest.raises(ChartError, match=r"short.csv:6"):
        load_chart(bad)
    with pytest.raises(ChartError, match="cannot read"):
        load_chart(tmp_path / "missing.csv")
    with pytest.raises(UnknownMethodError, match="colorchecker-classic"):
        get_chart("macbeth-dc")


def test_3x3_recovers_known_matrix_exactly_without_noise():
    virtual, _, real = _synthetic(0.0)
    fit = fit_ccm(virtual, real)
    np.testing.assert_allclose(fit.matrix, M_TRUE, atol=1e-10)
    assert fit.max_de00 < 1e-8


def test_3x3_recovers_known_matrix_from_noisy_patches():
    virtual, noisy, real = _synthetic(0.01)
    fit = fit_ccm(noisy, real)
    assert np.abs(fit.matrix - M_TRUE).max() < 0.03
    # residual report is right: recompute independently
    predicted = noisy @ fit.matrix.T
    expected = delta_E(prophoto_to_lab(predicted), prophoto_to_lab(real))
    np.testing.assert_allclose(fit.residual_de00, expected, atol=1e-10)
    assert fit.mean_de00 == pytest.approx(expected.mean())
    assert fit.max_de00 == pytest.approx(expected.max())
    assert fit.residual_de00.shape == (24,)
    # 1 % channel noise -> residuals of a few tenths of a dE00
    assert 0.05 < fit.mean_de00 < 1.5 and fit.max_de00 < 4.0
    print(f"CCM 3x3 on 1% noise: mean {fit.mean_de00:.3f} max {fit.max_de00:.3f} dE00")
    # applying the fit to new colours follows the true matrix
    rng = np.random.default_rng(0)
    fresh = rng.uniform(0.05, 0.6, (50, 3))
    assert residual_de00(fit.apply(fresh), fresh @ M_TRUE.T).mean() < 1.0


def test_root_polynomial_beside_3x3_and_exposure_invariance():
    _, noisy, real = _synthetic(0.01)
    both = compare_ccm_methods(noisy, real)
    assert set(both) == {"3x3", "root-polynomial"}
    rp = both["root-polynomial"]
    assert rp.matrix.shape == (3, 6) and rp.residual_de00.shape == (24,)
    # both are reported; on a linear mismatch neither is far worse
    assert rp.mean_de00 < 2 * both["3x3"].mean_de00 + 0.1
    for name, fit in both.items():
        print(f"CCM {name}: mean {fit.mean_de00:.3f} max {fit.max_de00:.3f} dE00")
    # root-polynomial terms are homogeneous of degree 1: scaling the input scales the output
    x = noisy[:5]
    np.testing.assert_allclose(rp.apply(2.0 * x), 2.0 * rp.apply(x), rtol=1e-10)


def test_root_polynomial_beats_3x3_on_a_nonlinear_mismatch():
    real = colorchecker_classic().prophoto()
    virtual = real**1.15 * real.sum(axis=1, keepdims=True) ** -0.15  # homogeneous distortion
    both = compare_ccm_methods(virtual, real)
    assert both["root-polynomial"].mean_de00 < both["3x3"].mean_de00


def test_ccm_bad_inputs():
    virtual, _, real = _synthetic(0.0)
    with pytest.raises(ShapeError, match="same shape"):
        fit_ccm(virtual[:20], real)
    with pytest.raises(ShapeError, match="at least 6 patches"):
        fit_ccm(virtual[:5], real[:5], "root-polynomial")
    bad = virtual.copy()
    bad[3, 1] = np.inf
    with pytest.raises(NonFiniteError, match="virtual"):
        fit_ccm(bad, real)
    grey = np.repeat(np.linspace(0.05, 0.9, 24)[:, None], 3, axis=1)
    with pytest.raises(ShapeError, match="chromatic"):
        fit_ccm(grey, real)
    with pytest.raises(UnknownMethodError, match="3x3"):
        fit_ccm(virtual, real, "thin-plate")
