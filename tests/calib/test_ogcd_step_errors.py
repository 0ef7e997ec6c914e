"""The standard errors of OGCD's steps follow how the batches move the curve: an offset shared
by every length (a tuft layout, common random numbers) leaves the steps nearly exact."""

from __future__ import annotations

import numpy as np

from grassd.calib.ogcd import ogcd_from_samples


def _batches(shared: float, own: float, seed: int = 0) -> np.ndarray:
    """(S, n, 3) linear RGB: a rising curve, every batch shifted by one factor common to all
    its lengths (``shared``) and by noise of its own per length (``own``)."""
    rng = np.random.default_rng(seed)
    s, n = 16, 9
    base = np.stack([np.linspace(0.05, 0.30, n), np.linspace(0.10, 0.40, n),
                     np.full(n, 0.05)], axis=1)
    common = 1.0 + shared * rng.standard_normal((s, 1, 1))
    return base[None] * common * (1.0 + own * rng.standard_normal((s, n, 3)))


def _jackknife_steps(x: np.ndarray) -> np.ndarray:
    """Jackknife standard errors of the steps of OGCD of the batch mean (leave one batch
    out): an estimate that does not linearise."""
    s = x.shape[0]
    steps = np.stack([np.diff(ogcd_from_samples(np.delete(x, i, axis=0)).ogcd)
                      for i in range(s)])
    return np.sqrt((s - 1) / s * ((steps - steps.mean(axis=0)) ** 2).sum(axis=0))


def test_step_errors_agree_with_the_jackknife():
    x = _batches(shared=0.05, own=0.01)
    res = ogcd_from_samples(x)
    np.testing.assert_allclose(res.step_stderr, _jackknife_steps(x), rtol=0.15)


def _step_ratio(shared: float, own: float) -> float:
    """Mean of step error / hypot of the two lengths' errors (steps after the first: the
    first starts at the reference, whose OGCD is exactly 0)."""
    res = ogcd_from_samples(_batches(shared, own))
    assert res.step_stderr.shape == (8,)
    hypot = np.hypot(res.ogcd_stderr[:-1], res.ogcd_stderr[1:])
    return float(np.mean(res.step_stderr[1:] / hypot[1:]))


def test_a_shift_shared_by_all_lengths_leaves_the_steps_nearly_exact():
    assert _step_ratio(shared=0.05, own=0.002) < 0.3  # measured 0.21


def test_noise_of_each_length_of_its_own_stays_in_the_steps():
    # the reference's noise is shared by every length, so steps keep somewhat less
    assert _step_ratio(shared=0.0, own=0.02) > 0.5  # measured 0.77
