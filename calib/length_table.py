"""8-bit length tables: the grass length for each 8-bit level, so equal level steps give equal
steps of perceived colour (OGCD).

Method (the paper's section 6.2): level v in 0..255 targets
``OGCD_target(v) = OGCD(x_min) + v / 255 * (OGCD(x_max) - OGCD(x_min))`` on the fitted
characteristic (OGCD(x_min) is 0 up to noise), and the table holds the inverse of the
characteristic at that target, rounded to whole micrometres. The linearity of OGCD vs level is
reported as the coefficient of determination R^2 of a least-squares line, for the uncalibrated
mapping (length linear in level, x_min .. x_max) and for the table, both evaluated on the fitted
characteristic (paper, real pixel: 0.956 before, 0.999 after).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from grassd.calib.array_checks import as_float_array
from grassd.calib.characteristic import (
    MIN_OGCD_RANGE,
    Characteristic,
    FittedCharacteristic,
    fit_characteristic,
)
from grassd.calib.errors import FlatCharacteristicError, ShapeError

#: Number of entries of an 8-bit table.
LEVELS: int = 256
_UM_PER_MM: float = 1000.0


@dataclass(frozen=True, eq=False)
class LengthTable:
    """Grass length per 8-bit level and how linear it makes the colour.

    Attributes:
        lengths_um: (256,) uint16 grass lengths in micrometres, non-decreasing;
            entry 0 is the minimum length.
        target_ogcd: (256,) OGCD each level aims at (CIEDE2000).
        achieved_ogcd: (256,) fitted OGCD at the rounded table lengths.
        uncalibrated_ogcd: (256,) fitted OGCD when length is linear in level.
        r2_before: R^2 of OGCD vs level, uncalibrated (linear-length) mapping.
        r2_after: R^2 of OGCD vs level with this table.
        ogcd_range: fitted OGCD range covered (CIEDE2000).
        max_level_error: largest |achieved - target| OGCD over the levels (CIEDE2000).
    """

    lengths_um: NDArray[np.uint16]
    target_ogcd: NDArray[np.float64]
    achieved_ogcd: NDArray[np.float64]
    uncalibrated_ogcd: NDArray[np.float64]
    r2_before: float
    r2_after: float
    ogcd_range: float
    max_level_error: float

    @property
    def lengths_mm(self) -> NDArray[np.float64]:
        """The table in millimetres (float)."""
        return self.lengths_um.astype(np.float64) / _UM_PER_MM


def r_squared(levels: ArrayLike, values: ArrayLike) -> float:
    """Coefficient of determination of the least-squares line ``values ~ a + b * levels``.

    >>> r_squared([0, 1, 2, 3], [1.0, 3.0, 5.0, 7.0])
    1.0
    """
    x = as_float_array(levels, "levels", ndim=1)
    y = as_float_array(values, "values", ndim=1)
    if x.size != y.size or x.size < 3:
        raise ShapeError(
            f"r_squared needs equal-length arrays of >= 3 points; got {x.size}, {y.size}"
        )
    slope, intercept = np.polyfit(x, y, 1)
    ss_res = float(np.sum((y - (intercept + slope * x)) ** 2))
    ss_tot = float(np.sum((y - y.mean()) ** 2))
    if ss_tot == 0.0:
        raise FlatCharacteristicError("OGCD does not vary with level; R^2 is undefined")
    return 1.0 - ss_res / ss_tot


def build_length_table(
    characteristic: Characteristic | FittedCharacteristic,
    *,
    min_range: float = MIN_OGCD_RANGE,
) -> LengthTable:
    """The 256-entry length table (uint16 micrometres) that linearises OGCD vs 8-bit level.

    Args:
        characteristic: raw (fitted here with :func:`fit_characteristic`) or already fitted.
        min_range: smallest OGCD range (CIEDE2000) for which a table is built.

    Raises:
        FlatCharacteristicError: OGCD range below ``min_range``.
        TooFewLengthsError, InvalidArrayError: bad characteristic data.
    """
    fit = (
        characteristic
        if isinstance(characteristic, FittedCharacteristic)
        else fit_characteristic(characteristic, min_range=min_range)
    )
    if fit.ogcd_range < min_range:
        raise FlatCharacteristicError(
            f"the fitted OGCD range is {fit.ogcd_range:.3f} dE00 (< {min_range}): no useful table"
        )
    if fit.max_length_mm * _UM_PER_MM > np.iinfo(np.uint16).max:
        raise ShapeError(
            f"lengths up to {fit.max_length_mm} mm do not fit uint16 micrometres (max 65.535 mm); "
            "give lengths in millimetres"
        )
    levels = np.arange(LEVELS, dtype=np.float64)
    lo, hi = fit.ogcd_min, fit.ogcd_max
    target = lo + levels / (LEVELS - 1) * (hi - lo)
    lengths = fit.inverse(target)
    lengths[0] = fit.min_length_mm
    um = np.rint(lengths * _UM_PER_MM)
    lo_um, hi_um = np.rint([fit.min_length_mm * _UM_PER_MM, fit.max_length_mm * _UM_PER_MM])
    um = np.maximum.accumulate(np.clip(um, lo_um, hi_um))
    table = um.astype(np.uint16)
    achieved = fit(table / _UM_PER_MM)
    linear_lengths = fit.min_length_mm + levels / (LEVELS - 1) * (
        fit.max_length_mm - fit.min_length_mm
    )
    uncalibrated = fit(linear_lengths)
    return LengthTable(
        lengths_um=table,
        target_ogcd=target,
        achieved_ogcd=achieved,
        uncalibrated_ogcd=uncalibrated,
        r2_before=r_squared(levels, uncalibrated),
        r2_after=r_squared(levels, achieved),
        ogcd_range=float(hi - lo),
        max_level_error=float(np.abs(achieved - target).max()),
    )
