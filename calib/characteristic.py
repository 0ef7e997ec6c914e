"""Grass colour characteristics (OGCD vs grass length) and their monotone, smooth fit.

A :class:`Characteristic` holds measured or simulated OGCD values at grass lengths (mm). The
:func:`fit_characteristic` turns it into a :class:`FittedCharacteristic`: a monotone
non-decreasing, continuously differentiable function of length with an exact inverse.

Choice of fit: **weighted isotonic regression, then PCHIP through the pooled blocks**.

1. Isotonic regression (pool-adjacent-violators, ``scipy.optimize.isotonic_regression``) is the
   least-squares non-decreasing fit, weighted by ``1/stderr**2`` when standard errors are known.
   It needs no shape assumption and removes exactly the non-monotone part of the noise, e.g.
   the noisy plateau while the green blades are still hidden under the yellow ones, or a dip
   from a Monte Carlo outlier. Runs of violators are pooled into blocks.
2. Each block becomes one knot (weighted mean length, block value), so the knots are strictly
   increasing; the first and last blocks also get a knot at the end of the measured range (the
   curve is flat there if they were pooled). A piecewise-cubic Hermite interpolant (PCHIP,
   Fritsch & Carlson 1980) through the knots is C1 and, unlike a cubic spline, preserves
   monotonicity without overshoot.

Why not a smoothing spline: with the 10-25 lengths of a real sweep a smoothing parameter cannot
be estimated reliably, and over-smoothing flattens the S-shape that the 8-bit table exists to
linearise; monotone data are therefore interpolated, not smoothed. The inverse is computed by
vectorised bisection and returns the shortest length reaching a given OGCD, so it is defined on
flat stretches too.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.interpolate import PchipInterpolator
from scipy.optimize import isotonic_regression

from grassd.calib.array_checks import as_float_array, same_shape
from grassd.calib.errors import FlatCharacteristicError, ShapeError, TooFewLengthsError
from grassd.calib.ogcd import ogcd_from_lab, ogcd_from_rgb

#: A characteristic needs at least this many distinct grass lengths.
MIN_DISTINCT_LENGTHS: int = 3
#: Below this OGCD range (CIEDE2000) a characteristic is flat: no useful 8-bit table.
MIN_OGCD_RANGE: float = 0.5
#: Smallest standard error (CIEDE2000) a point keeps when it is fitted: the fit weights points by
#: 1/stderr**2, and a Monte Carlo estimate whose replicates agree exactly has a stderr of 0.
MIN_OGCD_STDERR: float = 1e-6


def floor_stderr(stderr: ArrayLike) -> NDArray[np.floating]:
    """Standard errors of OGCD (dE00) floored at :data:`MIN_OGCD_STDERR`, so that every point
    keeps a finite fit weight 1/stderr**2 in :func:`fit_characteristic`."""
    return np.maximum(stderr, MIN_OGCD_STDERR)


@dataclass(frozen=True, eq=False)
class Characteristic:
    """OGCD (CIEDE2000 units) at grass lengths (mm), sorted by length on construction.

    Attributes:
        lengths_mm: (n,) grass lengths, mm, >= 0 (may repeat: repeated measurements).
        ogcd: (n,) OGCD values, >= 0.
        ogcd_stderr: (n,) standard errors of ``ogcd`` or None.
    """

    lengths_mm: NDArray[np.float64]
    ogcd: NDArray[np.float64]
    ogcd_stderr: NDArray[np.float64] | None = None

    def __post_init__(self) -> None:
        x = as_float_array(self.lengths_mm, "lengths_mm", ndim=1, non_negative=True)
        y = as_float_array(self.ogcd, "ogcd", ndim=1, non_negative=True)
        same_shape(x, y, "lengths_mm", "ogcd")
        distinct = np.unique(x).size
        if distinct < MIN_DISTINCT_LENGTHS:
            raise TooFewLengthsError(
                f"a characteristic needs at least {MIN_DISTINCT_LENGTHS} distinct grass lengths; "
                f"got {distinct} ({np.unique(x).tolist()} mm): measure or render more lengths"
            )
        order = np.argsort(x, kind="stable")
        object.__setattr__(self, "lengths_mm", x[order])
        object.__setattr__(self, "ogcd", y[order])
        if self.ogcd_stderr is not None:
            s = as_float_array(self.ogcd_stderr, "ogcd_stderr", ndim=1, non_negative=True)
            same_shape(x, s, "lengths_mm", "ogcd_stderr")
            object.__setattr__(self, "ogcd_stderr", s[order])

    @classmethod
    def from_lab(cls, lengths_mm: ArrayLike, lab: ArrayLike) -> Characteristic:
        """From CIELAB (n, 3) at lengths (n,); the reference is the Lab at the minimum length."""
        x = as_float_array(lengths_mm, "lengths_mm", ndim=1, non_negative=True)
        lab_arr = as_float_array(lab, "lab", last_dim=3, ndim=2)
        if lab_arr.shape[0] != x.size:
            raise ShapeError(f"need one Lab row per length; got {lab_arr.shape[0]} and {x.size}")
        order = np.argsort(x, kind="stable")
        return cls(x[order], ogcd_from_lab(lab_arr[order]))

    @classmethod
    def from_rgb(
        cls,
        lengths_mm: ArrayLike,
        rgb: ArrayLike,
        rgb_stderr: ArrayLike | None = None,
        *,
        space: str = "rec709",
        ccm: object | None = None,
    ) -> Characteristic:
        """From linear RGB (n, 3) at lengths (n,); see :func:`~grassd.calib.ogcd.ogcd_from_rgb`."""
        x = as_float_array(lengths_mm, "lengths_mm", ndim=1, non_negative=True)
        arr = as_float_array(rgb, "rgb", last_dim=3, ndim=2, non_negative=True)
        if arr.shape[0] != x.size:
            raise ShapeError(f"need one RGB row per length; got {arr.shape[0]} and {x.size}")
        order = np.argsort(x, kind="stable")
        se = None
        if rgb_stderr is not None:
            se = as_float_array(rgb_stderr, "rgb_stderr", last_dim=3, ndim=2, non_negative=True)
            same_shape(arr, se, "rgb", "rgb_stderr")
            se = se[order]
        res = ogcd_from_rgb(arr[order], se, space=space, ccm=ccm)  # type: ignore[arg-type]
        return cls(x[order], res.ogcd, res.ogcd_stderr)


@dataclass(frozen=True, eq=False)
class FittedCharacteristic:
    """Monotone C1 fit of OGCD vs grass length, evaluable and invertible (lengths in mm).

    Attributes:
        knots_mm, knot_ogcd: the strictly increasing knots of the PCHIP (pooled blocks).
        min_length_mm, max_length_mm: the measured length range (the domain).
        data: the characteristic that was fitted.
    """

    knots_mm: NDArray[np.float64]
    knot_ogcd: NDArray[np.float64]
    min_length_mm: float
    max_length_mm: float
    data: Characteristic

    def __post_init__(self) -> None:
        object.__setattr__(self, "_pchip", PchipInterpolator(self.knots_mm, self.knot_ogcd))

    def __call__(self, lengths_mm: ArrayLike) -> NDArray[np.float64]:
        """Fitted OGCD at lengths (mm); lengths outside the measured range are clipped to it."""
        x = as_float_array(lengths_mm, "lengths_mm")
        return self._pchip(np.clip(x, self.min_length_mm, self.max_length_mm))  # type: ignore

    @property
    def ogcd_min(self) -> float:
        """Fitted OGCD at the minimum length."""
        return float(self(self.min_length_mm))

    @property
    def ogcd_max(self) -> float:
        """Fitted OGCD at the maximum length."""
        return float(self(self.max_length_mm))

    @property
    def ogcd_range(self) -> float:
        """Fitted OGCD range over the measured lengths (CIEDE2000 units)."""
        return self.ogcd_max - self.ogcd_min

    def inverse(self, ogcd: ArrayLike) -> NDArray[np.float64]:
        """Shortest length (mm) whose fitted OGCD reaches ``ogcd``; clipped to the range.

        Vectorised bisection to 1e-9 mm (the fit is monotone non-decreasing).
        """
        target = as_float_array(ogcd, "ogcd")
        lo = np.full(target.shape, self.min_length_mm)
        hi = np.full(target.shape, self.max_length_mm)
        below = target <= self.ogcd_min
        iterations = int(
            np.ceil(np.log2(max(self.max_length_mm - self.min_length_mm, 1e-12) / 1e-9))
        )
        for _ in range(max(iterations, 1)):
            mid = 0.5 * (lo + hi)
            ok = self(mid) >= target
            hi = np.where(ok, mid, hi)
            lo = np.where(ok, lo, mid)
        return np.where(below, self.min_length_mm, hi)


def fit_characteristic(
    characteristic: Characteristic, *, min_range: float = MIN_OGCD_RANGE
) -> FittedCharacteristic:
    """Monotone C1 fit of a characteristic: weighted isotonic regression, then PCHIP.

    Args:
        characteristic: OGCD vs length (with optional standard errors used as weights).
        min_range: smallest acceptable fitted OGCD range (CIEDE2000); below it the
            characteristic is flat and :class:`FlatCharacteristicError` is raised.
    """
    c = characteristic
    x, y = c.lengths_mm, c.ogcd
    if c.ogcd_stderr is not None:
        se = c.ogcd_stderr
        positive = se[se > 0]
        floor = 0.1 * float(np.median(positive)) if positive.size else 1.0
        w = 1.0 / np.maximum(se, floor) ** 2
    else:
        w = np.ones_like(y)
    # pool repeated lengths: weighted means
    ux, inv = np.unique(x, return_inverse=True)
    wsum = np.bincount(inv, weights=w)
    uy = np.bincount(inv, weights=w * y) / wsum
    iso = isotonic_regression(uy, weights=wsum, increasing=True).x
    # pool equal consecutive values into blocks; one knot per block at its weighted mean length,
    # except that the first and last blocks also keep the ends of the measured range (flat there)
    scale = max(1.0, float(np.abs(iso).max()))
    new_block = np.concatenate(([True], np.diff(iso) > 1e-12 * scale))
    block = np.cumsum(new_block) - 1
    bw = np.bincount(block, weights=wsum)
    kx = np.bincount(block, weights=wsum * ux) / bw
    ky = iso[new_block]
    if kx.size < 2:
        raise FlatCharacteristicError(
            f"the characteristic never increases (OGCD range 0 after a monotone fit of "
            f"{x.size} points); a flat curve cannot give an 8-bit table: check that the green "
            "grass length actually changes and that the measurements are of the right pixel"
        )
    if kx[0] > ux[0]:
        kx, ky = np.concatenate(([ux[0]], kx)), np.concatenate(([ky[0]], ky))
    if kx[-1] < ux[-1]:
        kx, ky = np.concatenate((kx, [ux[-1]])), np.concatenate((ky, [ky[-1]]))
    fit = FittedCharacteristic(
        knots_mm=kx, knot_ogcd=ky, min_length_mm=float(ux[0]), max_length_mm=float(ux[-1]), data=c
    )
    if fit.ogcd_range < min_range:
        raise FlatCharacteristicError(
            f"the fitted OGCD range is {fit.ogcd_range:.3f} dE00, below {min_range} dE00: the "
            "colour barely changes with length, so an 8-bit table would be meaningless; check "
            "the light (too dark?), the viewpoint and the grass lengths measured"
        )
    return fit
