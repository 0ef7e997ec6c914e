"""The checks that decide whether a measurement's photos are evidence
(:mod:`grassd.daemon.measure.evidence`), on photos made from a known truth: honest photos pass;
a fit pushed to its bounds, a noisy repeat, one photo of another state and verification photos
that disagree are each refused with their own kind; the shot order is drawn afresh each time."""

from __future__ import annotations

import numpy as np

from grassd.daemon.core.calibration.variation import DisplayVariation
from grassd.daemon.measure.evidence import (
    MAX_PHOTO_NOISE_LAB,
    RESIDUAL_FACTOR,
    Refusal,
    judge,
    name_mismatches,
    shot_order,
    verify,
)

N, K = 32, 12
NAMES = [f"shot-{k:02d}" for k in range(K)]
MODEL_SD = 0.3


def _photos(seed: int = 1, noise: float = 0.2) -> tuple[np.ndarray, np.ndarray]:
    """(measured, predicted) CIELAB (N, K, 3): a smooth prediction and photos of it with
    ``noise`` rms Lab."""
    rng = np.random.default_rng(seed)
    predicted = np.stack([np.linspace(30, 60, K)[None, :].repeat(N, 0),
                          np.linspace(-20, -5, K)[None, :].repeat(N, 0),
                          np.linspace(40, 20, K)[None, :].repeat(N, 0)], axis=-1)
    return predicted + rng.normal(0, noise, predicted.shape), predicted


def _judge(measured, predicted, variation=None, repeat=None, rms=None):
    variation = variation or DisplayVariation.none(N)
    repeat = repeat or (measured[:, 0], measured[:, 0] + 0.05)
    rms = np.full(N, 0.25) if rms is None else rms
    return judge(NAMES, measured, predicted, rms, variation, repeat, MODEL_SD, NAMES)


def test_honest_photos_are_evidence():
    ev = _judge(*_photos())
    assert ev.accepted and ev.refusals() == () and ev.reason() == ""
    assert 0.3 <= ev.noise_lab < 0.31
    assert max(ev.shot_rms_lab.values()) < 0.3
    assert ev.to_json()["accepted"] is True


def test_a_fit_at_its_bounds_is_refused():
    v = DisplayVariation.none(N)
    v.length_offset_mm[:5] = 5.0  # 5 of 32 at +5 mm: over 10 %
    ev = _judge(*_photos(), variation=v)
    assert ev.refusals() == (Refusal.OFFSETS_AT_BOUND,) and ev.at_bound == 5
    v.length_offset_mm[:5] = 4.0  # large, but inside its bound
    v.green_gain[:3] = 0.25  # 3 of 32 at a gain bound: within 10 %
    assert _judge(*_photos(), variation=v).accepted


def test_a_fit_residual_far_above_the_noise_is_refused():
    ev = _judge(*_photos(), rms=np.full(N, RESIDUAL_FACTOR * 0.31))
    assert ev.refusals() == (Refusal.FIT_RESIDUAL,)


def test_a_noisy_repeat_is_refused_and_cannot_widen_the_limits():
    measured, predicted = _photos()
    measured[:, 5] += 5.0  # one photo of another state, 5 Lab off everywhere
    repeat = (measured[:, 0], measured[:, 0] + 20.0)
    ev = _judge(measured, predicted, repeat=repeat)
    assert Refusal.PHOTO_NOISE in ev.refusals()
    assert ev.noise_lab <= np.hypot(MAX_PHOTO_NOISE_LAB, MODEL_SD) + 1e-9
    [mismatch] = [f for f in ev.findings if f.kind is Refusal.SHOT_MISMATCH]
    assert mismatch.shots == ("shot-05",)


def test_verification_photos_are_judged_against_the_prediction():
    measured, predicted = _photos()
    ev = _judge(measured, predicted)
    after, after_pred = _photos(seed=2)
    assert verify(ev, NAMES, after, after_pred).accepted
    swapped = after[:, ::-1]  # the verification photos in the reverse order
    bad = verify(ev, NAMES, swapped, after_pred)
    assert bad.refusals() == (Refusal.VERIFICATION,)
    assert len(bad.findings[0].shots) >= K - 2  # the middle two are near each other


def test_the_shot_order_is_drawn_afresh_with_one_repeat_never_right_after_its_first():
    names = [f"s{k}" for k in range(14)]
    orders = set()
    for _ in range(200):
        order, repeat = shot_order(names, repeat_of=names[:6])
        assert repeat is not None and sorted(order) == sorted([*names, repeat])
        first = repeat.removeprefix("repeat-")
        k = order.index(repeat)
        assert k == 0 or order[k - 1] != first
        orders.add(tuple(order))
    assert len(orders) == 200  # no two measurements alike
    assert shot_order(names)[1] is None


def test_a_wrong_photo_that_pulls_the_fit_is_named_alone():
    """A "model" that is one colour per pixel, fitted as the mean of the shots kept: one photo
    30 rms Lab off pulls every shot's residual by 30/K past a limit of 1.0, so the one fit names
    them all; left out and fitted again without it, only that photo is."""
    truth = _photos(noise=0.1)[0][:, :1].repeat(K, axis=1)  # one colour per pixel
    measured = truth + np.random.default_rng(3).normal(0, 0.1, truth.shape)
    measured[:, 4] += 30.0  # 30 rms Lab off

    def fit_of(photos: np.ndarray):
        return lambda kept: photos[:, kept].mean(axis=1, keepdims=True).repeat(K, axis=1)

    everything = np.ones(K, dtype=bool)
    rms, named = name_mismatches(measured, fit_of(measured)(everything), 1.0)
    assert named.sum() == K and rms[4] > 25  # every shot over the limit by the pulled fit
    rms, named = name_mismatches(measured, fit_of(measured)(everything), 1.0, fit_of(measured))
    assert list(np.flatnonzero(named)) == [4] and rms[4] > 29 and np.delete(rms, 4).max() < 0.5
    honest = measured.copy()
    honest[:, 4] = truth[:, 4]
    calls = []
    rms, named = name_mismatches(honest, fit_of(honest)(everything), 1.0,
                                 lambda kept: calls.append(kept) or fit_of(honest)(kept))
    assert not named.any() and calls == []  # nothing over the limit: no fit again
