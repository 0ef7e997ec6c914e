"""CIEDE2000 against Sharma, Wu & Dalal (2005) Table 1, and the dispatcher."""

from __future__ import annotations

from pathlib import Path

import colour
import numpy as np
import pytest

from grassd.calib.delta_e import DELTA_E_METHODS, delta_e, delta_e_cie1976, delta_e_cie2000
from grassd.calib.errors import CalibError, NonFiniteError, ShapeError, UnknownMethodError

DATA = Path(__file__).parent / "data" / "calib_sharma2005_ciede2000.csv"


def _sharma() -> np.ndarray:
    rows = [
        line.split(",")
        for line in DATA.read_text().splitlines()
        if line and not line.startswith("#") and not line.startswith("pair")
    ]
    return np.array(rows, dtype=float)


def test_table_has_all_34_pairs():
    t = _sharma()
    assert t.shape == (34, 8)
    assert t[:, 0].tolist() == list(range(1, 35))


def test_sharma_2005_table1_all_pairs_to_1e4():
    t = _sharma()
    got = delta_e_cie2000(t[:, 1:4], t[:, 4:7])
    assert np.abs(got - t[:, 7]).max() < 1e-4


def test_sharma_pairs_are_symmetric():
    t = _sharma()
    forward = delta_e_cie2000(t[:, 1:4], t[:, 4:7])
    backward = delta_e_cie2000(t[:, 4:7], t[:, 1:4])
    np.testing.assert_allclose(forward, backward, atol=1e-12)


def test_dispatcher_default_is_ciede2000_and_aliases_work():
    t = _sharma()
    for name in ("CIE 2000", "dE00", "ciede2000"):
        np.testing.assert_allclose(delta_e(t[:, 1:4], t[:, 4:7], method=name), t[:, 7], atol=1e-4)
    assert set(DELTA_E_METHODS) == {"CIE 2000", "CIE 1976"}
    assert delta_e([50, 0, 0], [53, 4, 0], method="dE76") == pytest.approx(5.0)


def test_matches_colour_science_on_random_pairs():
    rng = np.random.default_rng(7)
    a = np.column_stack([rng.uniform(0, 100, 5000), rng.uniform(-110, 110, (5000, 2))])
    b = a + rng.normal(0, 8, a.shape)
    ours = delta_e_cie2000(a, b)
    theirs = colour.delta_E(a, b, method="CIE 2000")
    np.testing.assert_allclose(ours, theirs, atol=1e-9)


def test_parametric_factors_scale_lightness_term():
    # pure lightness difference: dE00 = dL / (kL * SL)
    d1 = delta_e_cie2000([50, 0, 0], [60, 0, 0])
    d2 = delta_e_cie2000([50, 0, 0], [60, 0, 0], kL=2.0)
    assert d2 == pytest.approx(d1 / 2.0)


def test_broadcasting_against_one_reference():
    ref = np.array([50.0, 10.0, -10.0])
    many = np.tile(ref, (7, 1)) + np.arange(7)[:, None] * [1.0, 0.0, 0.0]
    out = delta_e(ref, many)
    assert out.shape == (7,)
    assert out[0] == 0.0 and np.all(np.diff(out) > 0)


def test_bad_inputs_raise_typed_errors():
    with pytest.raises(UnknownMethodError, match="CIE 2000"):
        delta_e([50, 0, 0], [50, 0, 0], method="CMC")
    with pytest.raises(ShapeError, match="last axis of length 3"):
        delta_e([50, 0], [50, 0])
    with pytest.raises(NonFiniteError, match="NaN"):
        delta_e([50, np.nan, 0], [50, 0, 0])
    with pytest.raises(ShapeError, match="broadcast"):
        delta_e_cie1976(np.zeros((4, 3)), np.zeros((5, 3)))
    assert issubclass(UnknownMethodError, CalibError)
