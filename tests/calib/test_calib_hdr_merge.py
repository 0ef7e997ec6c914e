"""calib.hdr_merge on synthetic brackets (pure numpy): response recovery, merging, and the
errors a bad bracket gets. The end-to-end round trip through a camera is in
tests/daemon/runtime/test_capture_round_trip.py."""

from __future__ import annotations

import numpy as np
import pytest

from grassd.calib.errors import BracketBlackError, BracketClippedError, HdrMergeError
from grassd.calib.hdr_merge import (
    merge_ldr,
    merge_linear,
    recover_response,
    relative_exposure,
)


def scene(h: int = 48, w: int = 96, seed: int = 0) -> np.ndarray:
    """Log-uniform radiance over 5 decades, colour varying smoothly."""
    rng = np.random.default_rng(seed)
    lum = 10.0 ** rng.uniform(-2.5, 2.5, (h, w))
    tint = np.stack([np.linspace(0.8, 1.2, w)] * h)
    return np.stack([lum * tint, lum, lum / tint], axis=-1)


def shoot(radiance: np.ndarray, exposures: np.ndarray, gamma: float = 2.2) -> list[np.ndarray]:
    return [np.clip(np.rint(np.clip(radiance * e, 0, 1) ** (1 / gamma) * 255), 0, 255)
            .astype(np.uint8) for e in exposures]


EXPOSURES = 4.0 ** np.arange(-6, 2)  # 8 shots, 2 EV apart


def test_recovered_response_matches_the_gamma_curve():
    shots = shoot(scene(), EXPOSURES, gamma=2.2)
    resp = recover_response(shots, EXPOSURES)
    codes = np.array([40, 80, 128, 180, 230])
    truth = (codes / 128.0) ** 2.2
    assert resp.shape == (256, 3) and (np.diff(resp, axis=0) > 0).all()
    np.testing.assert_allclose(resp[codes], np.stack([truth] * 3, axis=-1), rtol=0.05)


def test_merge_reproduces_the_scene_and_blocks_do_not_matter():
    rad = scene()
    shots = shoot(rad, EXPOSURES)
    resp = ((np.arange(256) + 1e-3) / 128.0)[:, None] ** 2.2 * np.ones(3)
    a = merge_ldr(shots, EXPOSURES, resp)
    b = merge_ldr(shots, EXPOSURES, resp, block_rows=7)
    np.testing.assert_array_equal(a.radiance, b.radiance)
    ratio = a.radiance[..., 1] / (rad[..., 1] * (255.0 / 128.0) ** 2.2)
    assert np.median(np.abs(ratio - 1)) < 0.02
    assert a.shots_used == len(EXPOSURES) and a.clipped_fraction == 0.0


def test_linear_merge_is_exact_without_noise():
    rad = scene()
    shots = [np.clip(rad * e, 0, 1).astype(np.float32) for e in EXPOSURES]
    m = merge_linear(shots, EXPOSURES)
    np.testing.assert_allclose(m.radiance, rad, rtol=1e-4)


def test_highlights_come_from_the_shortest_exposure_and_are_flagged_when_clipped():
    rad = scene()
    rad[10, 20] = 1e6  # a sun far beyond the shortest exposure
    m = merge_linear([np.clip(rad * e, 0, 1).astype(np.float32) for e in EXPOSURES], EXPOSURES)
    assert m.clipped[10, 20] and m.clipped.sum() == 1
    assert m.radiance[10, 20, 1] == pytest.approx(1.0 / EXPOSURES[0])  # the lower bound


def test_unusable_brackets_are_typed_errors():
    rad = scene()
    with pytest.raises(BracketClippedError, match="shortest"):
        merge_ldr(shoot(rad * 1e9, EXPOSURES), EXPOSURES, np.ones((256, 3)).cumsum(axis=0))
    with pytest.raises(BracketBlackError, match="longest"):
        recover_response(shoot(rad * 1e-9, EXPOSURES), EXPOSURES)
    shots = shoot(rad, EXPOSURES)
    with pytest.raises(HdrMergeError, match="distinct"):
        merge_ldr(shots, np.ones(len(shots)), np.ones((256, 3)).cumsum(axis=0))
    with pytest.raises(HdrMergeError, match="increase"):
        merge_ldr(shots, EXPOSURES, np.ones((256, 3)))
    with pytest.raises(HdrMergeError, match="shape"):
        merge_ldr([shots[0], shots[1][:10]], EXPOSURES[:2], np.ones((256, 3)).cumsum(axis=0))
    with pytest.raises(HdrMergeError, match="> 0 s"):
        relative_exposure(0.0)
    assert relative_exposure(0.01, 200, 2.0) == pytest.approx(0.005)
