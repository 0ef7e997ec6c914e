"""Origin grass colour difference (OGCD) with its standard error.

For CIELAB values at grass lengths x_0 < x_1 < ... < x_n the paper defines
``OGCD_i = dE00(Lab(x_0), Lab(x_i))`` (CIEDE2000 against the colour at the minimum length).
Here the inputs are usually linear RGB measurements (renders in linear Rec.709, captures in
ProPhoto linear), optionally corrected by a colour-correction matrix, then converted
ProPhoto -> XYZ (D50) -> CIELAB (D50 white) as set out in :mod:`grassd.calib.colour_spaces`.

Uncertainty. Renders carry Monte Carlo standard errors per channel. Two propagations are offered:

* :func:`ogcd_from_rgb` with ``rgb_stderr``: first-order (delta-method) propagation through a
  numerical Jacobian, treating all channels at all lengths as **independent**. The renderer uses
  common random numbers, so errors at different lengths are positively correlated, which makes
  the difference Lab_i - Lab_0 less uncertain than this: the result is the conservative
  (larger) independent-error figure.
* :func:`ogcd_from_samples` with S independent batch estimates per length (each batch rendered
  with its own random numbers, shared across lengths): the delta method with the sample
  covariance across lengths, so the positive correlation is accounted for.

Near OGCD = 0 the difference is not differentiable (a norm at its minimum) and the linearised
error is unreliable; at i = 0 the OGCD is exactly 0 and its standard error is reported as 0.

Colour differences are colour-science's :func:`colour.delta_E` (``method`` "CIE 2000", the
CIEDE2000 of Sharma, Wu & Dalal 2005, Color Res. Appl. 30(1):21-30; checked against their
Table 1 in ``tests/calib/test_calib_delta_e.py``), not a copy of our own: a studio job spends
too little of its time here for a faster copy to pay for itself (docs/calib/colour_chain.md).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray

from grassd.calib.array_checks import as_float_array, same_shape
from grassd.calib.colour_spaces import prophoto_to_lab, to_prophoto
from grassd.calib.errors import ShapeError


class _Correction(Protocol):
    def apply(self, rgb: ArrayLike) -> NDArray[np.float64]: ...


def delta_E(lab1: ArrayLike, lab2: ArrayLike, method: str = "CIE 2000"
            ) -> NDArray[np.float64]:
    """colour-science's :func:`colour.delta_E` (dE units of ``method``), imported on the
    first call: ``import colour`` loads its plotting too (matplotlib, pandas: about 100 MiB and
    seconds), which the daemon's idle process and the light commands go without."""
    from colour import delta_E as colour_delta_e

    return colour_delta_e(lab1, lab2, method=method)


@dataclass(frozen=True, eq=False)
class OGCDResult:
    """OGCD values (n,) in CIEDE2000 units, their standard errors (or None) and the Lab (n, 3);
    ``step_stderr`` (n - 1,): standard errors of the steps OGCD[i + 1] - OGCD[i] (or None).
    Estimates correlated across lengths (common random numbers, a tuft layout shared by all
    lengths) move the whole curve together, so a step's error is not
    ``hypot(stderr[i], stderr[i + 1])``: it can be far smaller."""

    ogcd: NDArray[np.float64]
    ogcd_stderr: NDArray[np.float64] | None
    lab: NDArray[np.float64]
    step_stderr: NDArray[np.float64] | None = None


def ogcd_from_lab(lab: ArrayLike, method: str = "CIE 2000") -> NDArray[np.float64]:
    """OGCD (n,) of CIELAB rows (n, 3) ordered by grass length; row 0 is the minimum length.

    >>> ogcd_from_lab([[50, 0, 0], [50, 0, 0], [60, 0, 0]]).round(4).tolist()
    [0.0, 0.0, 9.4706]
    """
    arr = as_float_array(lab, "lab", last_dim=3, ndim=2, min_size=1)
    return delta_E(arr[:1], arr, method=method)


def _to_lab_fn(space: str, ccm: _Correction | NDArray | None):
    def to_lab(rgb: NDArray[np.float64]) -> NDArray[np.float64]:
        pp = to_prophoto(rgb, space)
        if ccm is None:
            corrected = pp
        elif hasattr(ccm, "apply"):
            corrected = ccm.apply(pp)  # type: ignore[union-attr]
        else:
            corrected = pp @ np.asarray(ccm, dtype=np.float64).T
        return prophoto_to_lab(corrected)

    return to_lab


def _check_ccm(ccm: object) -> None:
    if ccm is not None and not hasattr(ccm, "apply"):
        m = np.asarray(ccm)
        if m.shape != (3, 3) or not np.isfinite(m).all():
            raise ShapeError(
                f"ccm must be a finite 3x3 matrix or a fitted correction; got {m.shape}"
            )


def _gradients(
    rgb: NDArray[np.float64], to_lab, method: str
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """d OGCD_i / d rgb_0 and d OGCD_i / d rgb_i, each (n, 3), by central differences.

    All 6 perturbed copies go through one Lab conversion and one colour-difference call
    (stacked arrays; the per-call overhead of the conversions dominated for small n)."""
    n = rgb.shape[0]
    h = 1e-6 * np.maximum(np.abs(rgb), 1e-3)  # (n, 3) step per row and channel
    step = h[None] * np.eye(3)[:, None, :]  # (3, n, 3): channel c of every row moved
    labs = to_lab(np.concatenate([rgb[None], rgb + step, rgb - step]).reshape(-1, 3))
    labs = labs.reshape(7, n, 3)
    lab, lab_up, lab_dn = labs[0], labs[1:4], labs[4:7]
    ref = np.broadcast_to(lab, (3, n, 3))
    first = np.broadcast_to(lab[:1], (3, n, 3))
    # the reference (row 0) moved, against every row; every row moved, against the reference
    de = delta_E(np.concatenate([np.broadcast_to(lab_up[:, :1], (3, n, 3)),
                                 np.broadcast_to(lab_dn[:, :1], (3, n, 3)), first, first]),
                 np.concatenate([ref, ref, lab_up, lab_dn]), method=method).reshape(4, 3, n)
    g0 = ((de[0] - de[1]) / (2.0 * h[0][:, None])).T
    gi = ((de[2] - de[3]) / (2.0 * h.T)).T
    g0[0] = 0.0
    gi[0] = 0.0
    return g0, gi


def ogcd_from_rgb(
    rgb: ArrayLike,
    rgb_stderr: ArrayLike | None = None,
    *,
    space: str = "rec709",
    ccm: _Correction | ArrayLike | None = None,
    method: str = "CIE 2000",
) -> OGCDResult:
    """OGCD (n,) from linear RGB (n, 3) ordered by grass length, with optional error propagation.

    Args:
        rgb: linear RGB measurements, row 0 at the minimum length, in ``space``.
        rgb_stderr: (n, 3) per-channel standard errors of ``rgb`` (same units), or None.
        space: "rec709" (renders) or "prophoto" (captures).
        ccm: colour correction applied in ProPhoto linear: a fitted
            :class:`~grassd.calib.ccm.ColourCorrection` or a 3x3 matrix; None for none.
        method: colour-difference method of :func:`colour.delta_E` (default CIEDE2000).

    Returns:
        :class:`OGCDResult`; ``ogcd_stderr`` is the independent-error (conservative under common
        random numbers) linearised standard error, None when ``rgb_stderr`` is None.
    """
    x = as_float_array(rgb, "rgb", last_dim=3, ndim=2, non_negative=True)
    _check_ccm(ccm)
    to_lab = _to_lab_fn(space, ccm)  # type: ignore[arg-type]
    lab = to_lab(x)
    ogcd = delta_E(lab[:1], lab, method=method)
    if rgb_stderr is None:
        return OGCDResult(ogcd=ogcd, ogcd_stderr=None, lab=lab)
    s = as_float_array(rgb_stderr, "rgb_stderr", last_dim=3, ndim=2, non_negative=True)
    same_shape(x, s, "rgb", "rgb_stderr")
    g0, gi = _gradients(x, to_lab, method)
    var = np.sum((g0 * s[0]) ** 2, axis=1) + np.sum((gi * s) ** 2, axis=1)
    var[0] = 0.0
    return OGCDResult(ogcd=ogcd, ogcd_stderr=np.sqrt(var), lab=lab)


def ogcd_from_samples(
    rgb_samples: ArrayLike,
    *,
    space: str = "rec709",
    ccm: _Correction | ArrayLike | None = None,
    method: str = "CIE 2000",
) -> OGCDResult:
    """OGCD of the mean of S independent estimates (S, n, 3), with correlation-aware errors.

    Each of the S batches gives linear RGB at all n lengths; errors may be correlated across
    lengths within a batch (common random numbers) but batches are independent. The standard
    error is the delta method with the sample covariance of the batch means, including the
    covariance between the reference length and length i: each batch's linearised deviation
    ``T[s, i] = g0_i . d[s, 0] + gi_i . d[s, i]`` (``g0``, ``gi`` the gradients of dE at the mean
    Lab's reference and length i, ``d`` the batch's deviation from the mean RGB) gives
    ``var(OGCD_i) = sum_s T[s, i]^2 / (S (S - 1))``, and the steps' errors (``step_stderr``)
    come from ``T[s, i + 1] - T[s, i]`` the same way.
    """
    x = as_float_array(rgb_samples, "rgb_samples", last_dim=3, ndim=3, non_negative=True)
    n_s = x.shape[0]
    if n_s < 2:
        raise ShapeError(f"rgb_samples needs at least 2 independent batches; got {n_s}")
    _check_ccm(ccm)
    mean = x.mean(axis=0)
    to_lab = _to_lab_fn(space, ccm)  # type: ignore[arg-type]
    lab = to_lab(mean)
    ogcd = delta_E(lab[:1], lab, method=method)
    g0, gi = _gradients(mean, to_lab, method)
    d = x - mean  # (S, n, 3)
    scale = 1.0 / ((n_s - 1) * n_s)  # covariance of the mean
    t = np.einsum("ia,sa->si", g0, d[:, 0]) + np.einsum("ia,sia->si", gi, d)  # (S, n)
    t[:, 0] = 0.0  # the reference's OGCD is 0 in every batch
    var = np.einsum("si,si->i", t, t) * scale
    steps = np.diff(t, axis=1)
    step_var = np.einsum("si,si->i", steps, steps) * scale
    return OGCDResult(ogcd=ogcd, ogcd_stderr=np.sqrt(np.clip(var, 0.0, None)), lab=lab,
                      step_stderr=np.sqrt(np.clip(step_var, 0.0, None)))
