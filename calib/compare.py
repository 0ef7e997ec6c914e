"""Comparing two characteristics: discrete Frechet distance and maximum OGCD error.

The paper compares a simulated with a measured characteristic by the discrete Frechet distance
between the two polylines (length mm, OGCD dE00) and by the largest OGCD difference at common
lengths (paper: Frechet 1.16 at the reference viewpoint).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from grassd.calib.array_checks import as_float_array
from grassd.calib.characteristic import Characteristic
from grassd.calib.errors import ShapeError


def _curve(points: ArrayLike, name: str) -> NDArray[np.float64]:
    p = as_float_array(points, name)
    if p.ndim == 1:
        p = p[:, None]
    if p.ndim != 2 or p.shape[0] < 1:
        raise ShapeError(f"{name} must be a (n, d) array of points; got shape {p.shape}")
    return p


def discrete_frechet(p: ArrayLike, q: ArrayLike) -> float:
    """Exact discrete Frechet distance between polylines ``p`` (n, d) and ``q`` (m, d).

    Eiter & Mannila (1994) dynamic programme
    ``ca[i, j] = max(d(p_i, q_j), min(ca[i-1, j], ca[i-1, j-1], ca[i, j-1]))``, evaluated one
    anti-diagonal (i + j = k) at a time with numpy: O(n m) work, O(n + m) Python steps.
    Euclidean point distance; 1-D inputs are treated as (n, 1).

    >>> discrete_frechet([[0, 0], [1, 0], [2, 0]], [[0, 1], [1, 1], [2, 1]])
    1.0
    """
    a = _curve(p, "p")
    b = _curve(q, "q")
    if a.shape[1] != b.shape[1]:
        raise ShapeError(f"p and q must have the same point dimension; got {a.shape}, {b.shape}")
    n, m = a.shape[0], b.shape[0]
    d = np.sqrt(((a[:, None, :] - b[None, :, :]) ** 2).sum(axis=-1))
    ca = np.full((n, m), np.inf)
    ca[0, 0] = d[0, 0]
    for k in range(1, n + m - 1):
        i = np.arange(max(0, k - m + 1), min(n - 1, k) + 1)
        j = k - i
        best = np.full(i.shape, np.inf)
        up = i > 0
        best[up] = ca[i[up] - 1, j[up]]
        left = j > 0
        best[left] = np.minimum(best[left], ca[i[left], j[left] - 1])
        diag = up & left
        best[diag] = np.minimum(best[diag], ca[i[diag] - 1, j[diag] - 1])
        ca[i, j] = np.maximum(d[i, j], best)
    return float(ca[-1, -1])


def characteristic_points(c: Characteristic, length_scale: float = 1.0) -> NDArray[np.float64]:
    """(n, 2) polyline (length_mm * length_scale, OGCD) of a characteristic."""
    return np.column_stack([c.lengths_mm * length_scale, c.ogcd])


def frechet_characteristics(
    a: Characteristic, b: Characteristic, length_scale: float = 1.0
) -> float:
    """Discrete Frechet distance between two characteristics as (length mm, OGCD) polylines.

    ``length_scale`` converts millimetres into OGCD-comparable units (1: 1 mm counts like
    1 dE00, as in the paper's plots).
    """
    return discrete_frechet(
        characteristic_points(a, length_scale), characteristic_points(b, length_scale)
    )


def max_ogcd_error(a: Characteristic, b: Characteristic) -> float:
    """Largest |OGCD_a - OGCD_b| over the union of both length samplings (dE00).

    Each characteristic is linearly interpolated at the lengths of both, restricted to the
    overlap of their length ranges (repeated lengths are averaged first).
    """
    lo = max(a.lengths_mm[0], b.lengths_mm[0])
    hi = min(a.lengths_mm[-1], b.lengths_mm[-1])
    if hi < lo:
        raise ShapeError(
            f"the characteristics do not overlap in length ([{a.lengths_mm[0]}, "
            f"{a.lengths_mm[-1]}] vs [{b.lengths_mm[0]}, {b.lengths_mm[-1]}] mm)"
        )
    grid = np.union1d(a.lengths_mm, b.lengths_mm)
    grid = grid[(grid >= lo) & (grid <= hi)]

    def interp(c: Characteristic) -> NDArray[np.float64]:
        ux, inv = np.unique(c.lengths_mm, return_inverse=True)
        uy = np.bincount(inv, weights=c.ogcd) / np.bincount(inv)
        return np.interp(grid, ux, uy)

    return float(np.abs(interp(a) - interp(b)).max())
