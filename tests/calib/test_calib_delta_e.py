"""The CIEDE2000 grassd uses (colour-science's ``colour.delta_E``, method "CIE 2000") against
Sharma, Wu & Dalal (2005) Table 1: a colour-science upgrade that changed it would show here."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from colour import delta_E

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
    got = delta_E(t[:, 1:4], t[:, 4:7], method="CIE 2000")
    assert np.abs(got - t[:, 7]).max() < 1e-4


def test_sharma_pairs_are_symmetric():
    t = _sharma()
    forward = delta_E(t[:, 1:4], t[:, 4:7], method="CIE 2000")
    backward = delta_E(t[:, 4:7], t[:, 1:4], method="CIE 2000")
    np.testing.assert_allclose(forward, backward, atol=1e-12)


def test_one_reference_broadcasts_against_many_as_ogcd_uses_it():
    ref = np.array([[50.0, 10.0, -10.0]])
    many = np.tile(ref, (7, 1)) + np.arange(7)[:, None] * [1.0, 0.0, 0.0]
    out = delta_E(ref, many, method="CIE 2000")
    assert out.shape == (7,)
    assert out[0] == 0.0 and np.all(np.diff(out) > 0)
