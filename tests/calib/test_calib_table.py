"""Characteristic fit and 8-bit length tables: monotonicity, endpoints, R^2, bad input."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from grassd.calib.characteristic import Characteristic, fit_characteristic
from grassd.calib.errors import (
    CalibError,
    FlatCharacteristicError,
    NegativeValueError,
    NonFiniteError,
    ShapeError,
    TooFewLengthsError,
)
from grassd.calib.length_table import LEVELS, build_length_table, r_squared

LENGTHS = np.linspace(0.0, 20.0, 21)


def logistic(x, mid=11.0, width=1.5, top=12.0):
    y = top / (1 + np.exp(-(x - mid) / width))
    return y - top / (1 + np.exp(mid / width))


S_CURVES = {
    "logistic": lambda x: logistic(x),
    "early-steep": lambda x: logistic(x, mid=6.0, width=1.0, top=9.0),
    "late-wide": lambda x: logistic(x, mid=14.0, width=3.0, top=20.0),
    "smoothstep": lambda x: 15.0 * (3 * (x / 20) ** 2 - 2 * (x / 20) ** 3),
    "tanh": lambda x: 8.0 * (1 + np.tanh((x - 10.0) / 2.5)) - 8.0 * (1 + np.tanh(-4.0)),
}


def _check_table(table, fit) -> None:
    lut = table.lengths_um
    assert lut.shape == (LEVELS,) and lut.dtype == np.uint16
    assert np.all(np.diff(lut.astype(int)) >= 0)
    assert lut[0] == round(fit.min_length_mm * 1000)
    assert lut.max() <= round(fit.max_length_mm * 1000)


@pytest.mark.parametrize("name", sorted(S_CURVES))
def test_smooth_s_curves_give_r2_after_at_least_0999(name):
    char = Characteristic(LENGTHS, S_CURVES[name](LENGTHS))
    fit = fit_characteristic(char)
    table = build_length_table(fit)
    _check_table(table, fit)
    assert table.lengths_um[0] == 0 and table.lengths_um[-1] == 20000  # strictly rising ends
    assert table.r2_after >= 0.999
    assert table.r2_before < table.r2_after
    assert table.ogcd_range == pytest.approx(S_CURVES[name](20.0), rel=1e-9)
    # each level lands on its target to well under a just-noticeable difference
    assert table.max_level_error < 0.01
    print(f"table {name}: R2 before {table.r2_before:.4f} after {table.r2_after:.6f}")


def test_noisy_non_monotone_curve_still_gives_a_monotone_table():
    rng = np.random.default_rng(2024)
    y = np.clip(logistic(LENGTHS) + rng.normal(0, 0.4, LENGTHS.size), 0, None)
    y[0] = 0.0
    assert np.any(np.diff(y) < 0)  # the raw curve is not monotone
    char = Characteristic(LENGTHS, y, np.full_like(y, 0.4))
    fit = fit_characteristic(char)
    dense = fit(np.linspace(0, 20, 4001))
    assert np.all(np.diff(dense) >= -1e-12)
    table = build_length_table(fit)
    _check_table(table, fit)
    assert table.r2_after >= 0.999
    print(f"table noisy: R2 before {table.r2_before:.4f} after {table.r2_after:.6f}")
    # the fit stays close to the truth it was drawn from
    assert np.abs(fit(LENGTHS) - logistic(LENGTHS)).max() < 1.5


def test_fit_interpolates_monotone_data_and_inverts():
    y = logistic(LENGTHS)
    fit = fit_characteristic(Characteristic(LENGTHS, y))
    np.testing.assert_allclose(fit(LENGTHS), y, atol=1e-12)
    targets = np.linspace(fit.ogcd_min, fit.ogcd_max, 101)
    np.testing.assert_allclose(fit(fit.inverse(targets)), targets, atol=1e-6)
    assert fit.inverse(-1.0) == 0.0 and fit.inverse(1e6) == pytest.approx(20.0)
    # between knots the C1 fit is close to the smooth truth
    fine = np.linspace(0, 20, 801)
    assert np.abs(fit(fine) - logistic(fine)).max() < 0.1


def test_stderr_weights_protect_well_measured_points():
    y = logistic(LENGTHS)
    y_bad = y.copy()
    y_bad[12] = y[10]  # one dip below its neighbour
    se = np.full_like(y, 0.05)
    se[12] = 5.0  # ... but it is known to be poor
    fit = fit_characteristic(Characteristic(LENGTHS, y_bad, se))
    assert fit(11.0) == pytest.approx(y[11], abs=0.05)
    unweighted = fit_characteristic(Characteristic(LENGTHS, y_bad))
    assert abs(unweighted(11.0) - y[11]) > abs(fit(11.0) - y[11])


def test_repeated_lengths_and_unsorted_input():
    x = np.r_[LENGTHS, LENGTHS[::-1]]
    y = np.r_[logistic(LENGTHS) + 0.1, logistic(LENGTHS[::-1]) - 0.1]
    char = Characteristic(x, np.clip(y, 0, None))
    assert np.all(np.diff(char.lengths_mm) >= 0)
    fit = fit_characteristic(char)
    assert fit(15.0) == pytest.approx(logistic(15.0), abs=0.02)


def test_r_squared_reference_values():
    assert r_squared([0, 1, 2, 3], [0, 1, 2, 3]) == pytest.approx(1.0)
    # y = x^2 on 0..4 (hand computed): best line y = 4x - 2, SSres = 14, SStot = 174
    x = np.arange(5.0)
    y = x**2
    slope, intercept = np.polyfit(x, y, 1)
    expected = 1 - np.sum((y - slope * x - intercept) ** 2) / np.sum((y - y.mean()) ** 2)
    assert r_squared(x, y) == pytest.approx(expected)
    assert r_squared(x, y) == pytest.approx(1 - 14.0 / 174.0)


def test_bad_inputs_give_typed_errors_with_fixes():
    y = logistic(LENGTHS)
    with pytest.raises(NonFiniteError, match="NaN"):
        Characteristic(LENGTHS, np.where(LENGTHS == 5, np.nan, y))
    with pytest.raises(NonFiniteError):
        Characteristic(np.where(LENGTHS == 5, np.inf, LENGTHS), y)
    with pytest.raises(NegativeValueError, match="lengths_mm"):
        Characteristic(LENGTHS - 1.0, y)
    with pytest.raises(NegativeValueError, match="ogcd"):
        Characteristic(LENGTHS, y - 1.0)
    with pytest.raises(ShapeError, match="dimension"):
        Characteristic(LENGTHS, np.c_[y, y])
    with pytest.raises(ShapeError, match="same shape"):
        Characteristic(LENGTHS, y[:-1])
    with pytest.raises(TooFewLengthsError, match="at least 3 distinct"):
        Characteristic([1.0, 1.0, 2.0, 2.0], [0.0, 0.1, 3.0, 3.1])
    with pytest.raises(FlatCharacteristicError, match="below 0.5"):
        build_length_table(Characteristic(LENGTHS, 0.3 * y / y.max()))
    with pytest.raises(FlatCharacteristicError, match="never increases"):
        build_length_table(Characteristic(LENGTHS, y[::-1].copy()))
    with pytest.raises(ShapeError, match="micrometres"):
        build_length_table(Characteristic(LENGTHS * 1000, y))
    assert issubclass(FlatCharacteristicError, CalibError)


@st.composite
def characteristics(draw):
    n = draw(st.integers(min_value=3, max_value=30))
    steps = draw(st.lists(st.floats(0.05, 2.0), min_size=n - 1, max_size=n - 1))
    start = draw(st.floats(0.0, 5.0))
    lengths = start + np.r_[0.0, np.cumsum(steps)]
    ogcd = np.array(draw(st.lists(st.floats(0.0, 40.0), min_size=n, max_size=n)))
    ogcd[0] = 0.0
    return lengths, ogcd


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(characteristics())
def test_property_fit_and_table_are_monotone(data):
    lengths, ogcd = data
    char = Characteristic(lengths, ogcd)
    try:
        fit = fit_characteristic(char)
    except FlatCharacteristicError:
        return  # a legitimately flat or decreasing curve
    dense = fit(np.linspace(lengths[0], lengths[-1], 2001))
    assert np.all(np.diff(dense) >= -1e-9 * max(1.0, dense.max()))
    table = build_length_table(fit)
    _check_table(table, fit)
    assert np.all(np.diff(table.achieved_ogcd) >= -1e-9 * max(1.0, table.ogcd_range))
    assert table.lengths_um[0] == round(lengths[0] * 1000)


@settings(max_examples=100, deadline=None)
@given(
    mid=st.floats(3.0, 17.0),
    width=st.floats(0.8, 4.0),
    top=st.floats(2.0, 40.0),
)
def test_property_smooth_s_curves_reach_r2_0999(mid, width, top):
    y = logistic(LENGTHS, mid, width, top)
    table = build_length_table(Characteristic(LENGTHS, y))
    assert table.r2_after >= 0.999
    assert np.all(np.diff(table.lengths_um.astype(int)) >= 0)
