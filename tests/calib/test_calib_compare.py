"""Discrete Frechet distance against hand-computed cases and a brute-force recursion."""

from __future__ import annotations

from functools import cache

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from grassd.calib.characteristic import Characteristic
from grassd.calib.compare import discrete_frechet, frechet_characteristics, max_ogcd_error
from grassd.calib.errors import ShapeError


def _recursive_frechet(p: np.ndarray, q: np.ndarray) -> float:
    """Eiter & Mannila's recursive definition, memoised (the textbook form)."""

    @cache
    def c(i: int, j: int) -> float:
        d = float(np.linalg.norm(p[i] - q[j]))
        if i == 0 and j == 0:
            return d
        if i == 0:
            return max(c(0, j - 1), d)
        if j == 0:
            return max(c(i - 1, 0), d)
        return max(min(c(i - 1, j), c(i - 1, j - 1), c(i, j - 1)), d)

    return c(len(p) - 1, len(q) - 1)


def test_hand_cases():
    # parallel lines one apart
    assert discrete_frechet([[0, 0], [1, 0], [2, 0]], [[0, 1], [1, 1], [2, 1]]) == 1.0
    # identical curves, and a curve against a subsampled copy of itself (same vertices kept)
    p = [[0, 0], [1, 1], [2, 0], [3, 1]]
    assert discrete_frechet(p, p) == 0.0
    # a single point against a curve: the farthest vertex
    assert discrete_frechet([[0, 0]], [[3, 4], [0, 1], [6, 8]]) == 10.0
    # 1-D: P = 0, 2, 4; Q = 0, 4. Best coupling (0,0), (2,0) or (2,4), (4,4): distance 2
    assert discrete_frechet([0, 2, 4], [0, 4]) == 2.0
    # backtracking costs: P goes out and back, Q stays; the far end dominates
    assert discrete_frechet([0, 5, 0], [0, 0]) == 5.0
    # order matters (Frechet, not Hausdorff): reversed Q is far
    assert discrete_frechet([0, 1, 2, 3], [3, 2, 1, 0]) == 3.0
    # dog-walk example: P = (0,0),(1,0),(2,0); Q = (0,1),(2,1) -> sqrt(2)
    assert discrete_frechet([[0, 0], [1, 0], [2, 0]], [[0, 1], [2, 1]]) == pytest.approx(np.sqrt(2))


@settings(max_examples=60, deadline=None)
@given(
    n=st.integers(1, 9),
    m=st.integers(1, 9),
    seed=st.integers(0, 2**31 - 1),
)
def test_matches_recursive_definition(n, m, seed):
    rng = np.random.default_rng(seed)
    p = rng.normal(size=(n, 2))
    q = rng.normal(size=(m, 2))
    assert discrete_frechet(p, q) == pytest.approx(_recursive_frechet(p, q), abs=1e-12)
    assert discrete_frechet(p, q) == pytest.approx(discrete_frechet(q, p), abs=1e-12)


def test_characteristics_sampled_differently():
    xa = np.linspace(0, 20, 21)
    xb = np.linspace(0, 20, 11)
    a = Characteristic(xa, 0.5 * xa)
    b = Characteristic(xb, 0.5 * xb + 1.0)
    # b is a shifted up by 1; a's odd vertices sit between b's, so the coupling pays more than 1:
    # a's (1, 0.5) is sqrt(1 + 0.25) from b's (0, 1) and sqrt(1 + 2.25) from b's (2, 2).
    assert frechet_characteristics(a, b) == pytest.approx(np.sqrt(1.25))
    assert max_ogcd_error(a, b) == pytest.approx(1.0)
    # length_scale shrinks the length axis: only the OGCD offset remains
    assert frechet_characteristics(a, b, length_scale=1e-6) == pytest.approx(1.0, abs=1e-5)


def test_max_ogcd_error_interpolates_on_the_union_of_lengths():
    a = Characteristic([0.0, 10.0, 20.0], [0.0, 10.0, 10.0])
    b = Characteristic([0.0, 5.0, 15.0, 20.0], [0.0, 1.0, 10.0, 10.0])
    # at 5 mm: a = 5 (interpolated), b = 1 -> error 4; at 10 mm: a = 10, b = 5.5 -> 4.5
    assert max_ogcd_error(a, b) == pytest.approx(4.5)
    c = Characteristic([30.0, 31.0, 32.0], [0.0, 1.0, 2.0])
    with pytest.raises(ShapeError, match="overlap"):
        max_ogcd_error(a, c)
    with pytest.raises(ShapeError, match="dimension"):
        discrete_frechet(np.zeros((3, 2)), np.zeros((3, 3)))
