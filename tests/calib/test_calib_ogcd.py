"""OGCD from Lab and from linear RGB, and its standard error (delta method vs Monte Carlo)."""

from __future__ import annotations

import numpy as np
import pytest
from colour import delta_E

from grassd.calib.ccm import fit_ccm
from grassd.calib.charts import spyder_checkr_24
from grassd.calib.colour_spaces import prophoto_to_lab, rec709_to_prophoto
from grassd.calib.errors import NegativeValueError, ShapeError
from grassd.calib.ogcd import ogcd_from_lab, ogcd_from_rgb, ogcd_from_samples

YELLOW = np.array([0.55, 0.42, 0.11])  # linear Rec.709
GREEN = np.array([0.045, 0.16, 0.027])


def _sweep(n: int = 9) -> np.ndarray:
    c = np.linspace(0.0, 0.5, n)[:, None]
    return (1 - c) * YELLOW + c * GREEN


def test_ogcd_from_lab_is_de00_against_first_row():
    lab = np.array([[60.0, 5.0, 40.0], [58.0, 0.0, 38.0], [50.0, -10.0, 30.0]])
    out = ogcd_from_lab(lab)
    assert out[0] == 0.0
    assert out[1] == pytest.approx(float(delta_E(lab[0], lab[1])))
    assert out[2] == pytest.approx(float(delta_E(lab[0], lab[2])))


def test_ogcd_from_rgb_follows_the_pipeline():
    rgb = _sweep()
    res = ogcd_from_rgb(rgb, space="rec709")
    lab = prophoto_to_lab(rec709_to_prophoto(rgb))
    np.testing.assert_allclose(res.lab, lab)
    np.testing.assert_allclose(res.ogcd, delta_E(lab[:1], lab))
    assert res.ogcd_stderr is None
    assert np.all(np.diff(res.ogcd) > 0)
    # the same colours given in ProPhoto give the same OGCD
    np.testing.assert_allclose(
        ogcd_from_rgb(rec709_to_prophoto(rgb), space="prophoto").ogcd, res.ogcd, atol=1e-10
    )
    # exposure does not matter only after normalisation: OGCD depends on absolute Y
    assert not np.allclose(ogcd_from_rgb(2 * rgb).ogcd, res.ogcd)


def test_ccm_is_applied_in_prophoto():
    rgb = _sweep()
    m = np.array([[0.95, 0.05, 0.0], [0.02, 1.0, -0.02], [0.0, 0.04, 0.96]])
    direct = ogcd_from_rgb(rgb, ccm=m)
    lab = prophoto_to_lab(rec709_to_prophoto(rgb) @ m.T)
    np.testing.assert_allclose(direct.ogcd, delta_E(lab[:1], lab))
    real = spyder_checkr_24().prophoto()
    fit = fit_ccm(real @ np.linalg.inv(m).T, real)
    np.testing.assert_allclose(ogcd_from_rgb(rgb, ccm=fit).ogcd, direct.ogcd, atol=1e-8)


def test_stderr_matches_monte_carlo_for_independent_noise():
    rgb = _sweep()
    se = np.full_like(rgb, 0.004)
    res = ogcd_from_rgb(rgb, se)
    rng = np.random.default_rng(42)
    draws = np.array(
        [
            ogcd_from_rgb(np.clip(rgb + se * rng.standard_normal(rgb.shape), 0, None)).ogcd
            for _ in range(3000)
        ]
    )
    mc = draws.std(axis=0)
    assert res.ogcd_stderr[0] == 0.0
    # delta method within 15 % of the Monte Carlo spread away from OGCD = 0
    np.testing.assert_allclose(res.ogcd_stderr[2:], mc[2:], rtol=0.15)


def test_samples_account_for_positive_correlation():
    rgb = _sweep()
    rng = np.random.default_rng(3)
    n_batches, rho, sigma = 48, 0.9, 0.01

    def batches():
        common = rng.standard_normal((n_batches, 1, 3))
        own = rng.standard_normal((n_batches, rgb.shape[0], 3))
        return np.clip(rgb + sigma * (np.sqrt(rho) * common + np.sqrt(1 - rho) * own), 0, None)

    one = batches()
    res = ogcd_from_samples(one)
    np.testing.assert_allclose(res.ogcd, ogcd_from_rgb(one.mean(axis=0)).ogcd)
    truth = np.array([ogcd_from_rgb(batches().mean(axis=0)).ogcd for _ in range(400)]).std(axis=0)
    independent = ogcd_from_rgb(one.mean(axis=0), one.std(axis=0, ddof=1) / np.sqrt(n_batches))
    # correlation-aware error tracks the truth; the independent one is conservative (larger)
    np.testing.assert_allclose(res.ogcd_stderr[2:], truth[2:], rtol=0.35)
    assert np.all(independent.ogcd_stderr[2:] > 1.3 * res.ogcd_stderr[2:])


def test_bad_inputs():
    rgb = _sweep()
    with pytest.raises(NegativeValueError, match="rgb"):
        ogcd_from_rgb(rgb - 0.2)
    with pytest.raises(ShapeError, match="same shape"):
        ogcd_from_rgb(rgb, np.zeros((3, 3)))
    with pytest.raises(ShapeError, match="3x3"):
        ogcd_from_rgb(rgb, ccm=np.eye(4))
    with pytest.raises(ShapeError, match="2 independent"):
        ogcd_from_samples(rgb[None])
    with pytest.raises(ShapeError):
        ogcd_from_rgb(rgb[:, :2])
