"""The checks of a calibration run (dE00 = CIEDE2000 units, lengths in mm, tables in um).

* :func:`check_shape` refuses a characteristic that cannot make a table, as OpenVPCal refuses a
  calibration from a bad measurement: too many flat steps (|step| <= max(2 sigma, 1 % of the
  range)) or any wild step (a drop of more than 3 sigma + 10 % of the range).
* :func:`check_table` refuses a table that is not 256 finite, integer, non-decreasing entries
  within 0..green_max, or that moves more than ``max_jump_mm`` from the last one unless forced.
* :func:`check_levels` and :func:`pooled_characteristic` serve the closed loop (as ArgyllCMS
  dispcal re-measures and corrects until a dE threshold).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from grassd.calib.characteristic import Characteristic, floor_stderr
from grassd.calib.length_table import LEVELS
from grassd.daemon.core.errors import CalibrationRejected


def finite_or_none(x: float | None) -> float | None:
    """``x`` as a float, or None when it is missing or not finite (reports are strict JSON: a
    reused matrix has no residuals, so its mean/max dE00 are NaN)."""
    if x is None or not np.isfinite(x):
        return None
    return float(x)


def check_shape(lengths_mm: NDArray, ogcd: NDArray, stderr: NDArray | None,
                max_flat_fraction: float, step_stderr: NDArray | None = None
                ) -> dict[str, float]:
    """Refuse a characteristic with too many flat or any wild steps (see module docstring).

    ``stderr`` (n,): OGCD's standard errors [dE00]; ``step_stderr`` (n - 1,): those of its
    steps between neighbouring lengths, in the order given (sorted lengths), when known
    (:class:`grassd.calib.ogcd.OGCDResult`); otherwise a step's error is taken as
    ``hypot(stderr[i], stderr[i + 1])``, which overstates it when the errors move the whole
    curve together (a tuft layout does). Returns the step statistics; raises
    :class:`CalibrationRejected`.
    """
    order = np.argsort(lengths_mm, kind="stable")
    y = np.asarray(ogcd, float)[order]
    se = np.zeros_like(y) if stderr is None else np.asarray(stderr, float)[order]
    steps = np.diff(y)
    if step_stderr is not None and np.array_equal(order, np.arange(order.size)):
        noise = np.asarray(step_stderr, float)
    else:
        noise = np.sqrt(se[:-1] ** 2 + se[1:] ** 2)
    rng = float(y.max() - y.min())
    flat = np.abs(steps) <= np.maximum(2.0 * noise, 0.01 * rng)
    wild = steps < -(3.0 * noise + 0.10 * rng)
    flat_fraction = float(flat.mean()) if steps.size else 1.0
    stats = {"flat_fraction": flat_fraction, "wild_steps": int(wild.sum()), "range": rng}
    if wild.any():
        i = int(np.argmax(wild))
        x = np.asarray(lengths_mm, float)[order]
        raise CalibrationRejected(
            f"characteristic has a wild step: OGCD drops by {-steps[i]:.2f} dE00 between "
            f"{x[i]:g} and {x[i + 1]:g} mm (noise {noise[i]:.2f}); check the light inputs")
    if flat_fraction > max_flat_fraction:
        raise CalibrationRejected(
            f"characteristic is flat over {flat_fraction:.0%} of its steps (limit "
            f"{max_flat_fraction:.0%}): the light cannot show the grass; no table built")
    return stats


def check_levels(n: int) -> NDArray[np.int64]:
    """The 8-bit levels the closed loop re-simulates: ``n`` evenly spaced over 0..255, rounded,
    duplicates dropped (level 0 is the reference length, 255 the top of the range).

    >>> check_levels(5).tolist()
    [0, 64, 128, 191, 255]
    """
    return np.unique(np.rint(np.linspace(0, LEVELS - 1, n)).astype(np.int64))


def pooled_characteristic(xs: Sequence[NDArray], ys: Sequence[NDArray],
                          ses: Sequence[NDArray]) -> Characteristic:
    """One characteristic of every point simulated for a table so far (the first simulation's
    lengths [mm], OGCD and standard errors [dE00], then each closed-loop round's), the errors
    floored (:func:`grassd.calib.characteristic.floor_stderr`) so that every point keeps a
    finite fit weight: what a closed loop refits its table to."""
    return Characteristic(np.concatenate(xs), np.concatenate(ys),
                          floor_stderr(np.concatenate(ses)))


def check_table(lengths_um: NDArray, green_max_mm: float, previous_um: NDArray | None,
                max_jump_mm: float, force: bool, what: str = "table") -> int | None:
    """Sanity checks of a table (micrometres); returns the largest step from ``previous_um``.

    ``lengths_um``: one table (256,) or per-pixel tables (n, 256), every row checked;
    ``previous_um`` must broadcast against it (a (256,) table against (n, 256) compares every
    row). ``what`` names the table in messages (e.g. a controller). Raises
    :class:`CalibrationRejected` naming the first problem found.
    """
    t = np.asarray(lengths_um)
    if t.ndim not in (1, 2) or t.shape[-1] != LEVELS or t.size == 0:
        raise CalibrationRejected(f"{what} has shape {t.shape}, expected ({LEVELS},) or "
                                  f"(n_pixels, {LEVELS})")
    if not np.all(np.isfinite(t.astype(float))):
        raise CalibrationRejected(f"{what} holds non-finite entries")
    if np.any(np.diff(t.astype(np.int64), axis=-1) < 0):
        raise CalibrationRejected(f"{what} is not monotone (non-decreasing)")
    top = round(green_max_mm * 1000)
    if int(t.min()) < 0 or int(t.max()) > top:
        raise CalibrationRejected(f"{what} leaves the range 0..{top} um")
    if previous_um is None:
        return None
    jump = int(np.abs(t.astype(np.int64) - np.asarray(previous_um, np.int64)).max())
    if jump > max_jump_mm * 1000 and not force:
        raise CalibrationRejected(
            f"{what} differs from the active one by up to {jump / 1000:.2f} mm (limit "
            f"{max_jump_mm:g} mm): a wild jump; run `grassd calibrate --now --force` to accept it")
    return jump
