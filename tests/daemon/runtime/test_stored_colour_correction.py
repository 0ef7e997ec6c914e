"""The colour correction a run with a checker RAW fitted is kept for the runs without one, in
any form, and one that cannot be read is dropped with a warning, never fatal."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from grassd.calib.ccm import CCM_FORMS, select_ccm
from grassd.daemon.core.runtime.commit import CCM_META, last_ccm
from grassd.daemon.core.store.history import History


@pytest.mark.parametrize("form", list(CCM_FORMS))
def test_a_stored_correction_of_each_form_applies_as_before(tmp_path, form):
    rgb = np.random.default_rng(0).uniform(0.05, 0.9, (24, 3))
    fit = select_ccm(rgb, rgb ** 1.1 * rgb.sum(1, keepdims=True) ** -0.1, [form])
    with History(tmp_path / "state.db") as h:
        assert last_ccm(h) is None
        h.set_meta(CCM_META, fit.to_json())
        again = last_ccm(h)
    assert again is not None and again.form == form
    np.testing.assert_allclose(again.apply(rgb), fit.apply(rgb), rtol=1e-12)
    assert np.isnan(again.loo_mean_de00)  # its residuals are the fitting run's, not kept


def test_a_bare_matrix_from_earlier_versions_is_a_3x3(tmp_path):
    with History(tmp_path / "state.db") as h:
        h.set_meta(CCM_META, (2 * np.eye(3)).tolist())
        c = last_ccm(h)
    assert c is not None and c.form == "3x3"
    np.testing.assert_allclose(c.apply([[0.1, 0.2, 0.3]]), [[0.2, 0.4, 0.6]])


@pytest.mark.parametrize("stored", [
    {"method": "lut", "degree": 1, "matrix": np.eye(3).tolist()},
    {"method": "root-polynomial", "degree": 2, "matrix": np.eye(3).tolist()},
    [[1, 2], [3, 4]],
    "not a matrix",
])
def test_an_unreadable_correction_is_dropped_with_a_warning(tmp_path, caplog, stored):
    with History(tmp_path / "state.db") as h, caplog.at_level(logging.WARNING):
        h.set_meta(CCM_META, stored)
        assert last_ccm(h) is None
    assert "stored colour correction cannot be read" in caplog.text
