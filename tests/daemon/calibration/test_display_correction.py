"""The display's measured per-pixel correction turns every run's tables into per-pixel tables
read through each pixel's mapping, and is kept in the state directory for later runs."""

from __future__ import annotations

import json
import logging

import numpy as np

from grassd.daemon.core.calibration.correction import (
    DisplayCorrection,
    load_correction,
    saved_correction,
)
from grassd.daemon.core.calibration.result import CENTRE, CalibrationResult
from grassd.daemon.core.calibration.variation import DisplayVariation
from grassd.daemon.core.config.settings import load_default_config
from grassd.daemon.core.store.atomic import atomic_write_json
from grassd.daemon.core.store.layout import StateLayout


def _correction(n: int = 32, shift_mm: float = 0.5) -> DisplayCorrection:
    grid = np.linspace(0.0, 20.0, 41)
    offsets = np.linspace(-1.0, 1.0, n)
    commands = np.clip(grid[None, :] - offsets[:, None] + shift_mm, 0.0, 20.0)
    var = DisplayVariation(offsets, np.ones(n), np.ones(n))
    return DisplayCorrection(var, grid, commands, (4, 8), "20261127T120000Z")


def _centre_result() -> CalibrationResult:
    table = np.linspace(0, 20000, 256).astype(np.uint16)
    return CalibrationResult(granularity="global", source=CENTRE, shape=(3, 3), table_um=table,
                             controller_tables={}, units=[], unit_of_pixel=np.zeros(9, int),
                             ccm=None, ccm_source="default", lighting_notes=(),
                             transport="spectral")


def test_a_global_run_becomes_per_pixel_tables_through_each_pixels_mapping():
    cfg = load_default_config()
    corr = _correction()
    out = corr.apply(cfg, _centre_result())
    assert sorted(out.controller_tables) == sorted(c.name for c in cfg.controllers)
    first, second = (out.controller_tables[c.name] for c in cfg.controllers)
    assert first.shape == (16, 256) and second.shape == (16, 256)
    assert first.dtype == np.uint16
    nominal = np.linspace(0, 20000, 256) / 1000.0
    want = np.clip(nominal - corr.variation.length_offset_mm[20] + 0.5, 0, 20) * 1000
    inside = nominal < 18.0  # where neither end of the range clamps the mapping
    assert np.abs(second[4].astype(float) - want)[inside].max() <= 1.0  # display pixel 20
    assert out.correction == "20261127T120000Z"


def test_the_correction_reads_back_from_the_state_directory(tmp_path):
    cfg = load_default_config().with_state_dir(tmp_path)
    assert saved_correction(cfg) is None  # never measured: tables as before
    corr = _correction()
    atomic_write_json(StateLayout(tmp_path).correction, corr.to_json())
    back = saved_correction(cfg)
    assert back is not None and back.measurement == corr.measurement
    assert np.allclose(back.commands_mm, corr.commands_mm, atol=1e-4)
    assert np.array_equal(back.variation.length_offset_mm, corr.variation.length_offset_mm)


def test_a_correction_for_another_display_or_corrupt_is_ignored_with_a_warning(tmp_path, caplog):
    path = StateLayout(tmp_path).correction
    atomic_write_json(path, _correction().to_json())
    with caplog.at_level(logging.WARNING):
        assert load_correction(path, (8, 8)) is None
    assert "4 x 8 display" in caplog.text
    path.write_text(json.dumps({"measurement": "x", "shape": [4, 8]}))
    with caplog.at_level(logging.WARNING):
        assert load_correction(path, (4, 8)) is None
    assert "unusable" in caplog.text
