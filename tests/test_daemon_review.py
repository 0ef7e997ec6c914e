"""Regression tests of the daemon's release review: each test failed before its fix.

Real parts only: simulated controllers on ptys (SimulatedHardware), the real renderer at tiny
sample counts, a real tmpfs that fills up (when the tests run as root and may mount).
"""

from __future__ import annotations

import shutil

import numpy as np
from test_daemon_granularity import BASE, POLICY, drop

from grassd.daemon.calibrate import init_backend
from grassd.daemon.config import parse_config
from grassd.daemon.fleet import table_checksum
from grassd.daemon.service import Service
from grassd.daemon.sim_hardware import SimulatedHardware

PIXEL = '[tables]\ngranularity = "pixel"\ncheck_groups = 0\n'


def _pixel_config(tmp_path, first: str, second: str):
    text = BASE.replace('pixels = "0-1"', f'pixels = "{first}"').replace(
        'pixels = "2-3"', f'pixels = "{second}"')
    return parse_config(text + PIXEL, base_dir=tmp_path)


def _run_bundle(svc: Service, name: str, lux: float = 8000.0) -> dict:
    drop(svc.cfg.light.inbox, name, lux)
    [b] = svc.inbox.poll()
    return svc.process_bundle(b)


def test_pixel_tables_after_a_controllers_pixel_count_changed(tmp_path):
    """A controller that drives 3 pixels instead of 2 after a config change (restart with
    the same ports and state): the next run must not fail for ever comparing its new (3, 256)
    table with its old (2, 256) one, and gets its new table."""
    hw = tmp_path / "hw"
    sim = SimulatedHardware(_pixel_config(tmp_path, "0-1", "2-3"), hw)
    svc = Service(sim.start(), policy=POLICY)
    try:
        init_backend(svc.cfg)
        first = _run_bundle(svc, "b1")
        assert first["status"] == "ok", first
    finally:
        svc.shutdown()
        sim.stop()
    shutil.rmtree(hw / "eeprom")  # re-flashed controllers with the new pixel counts

    sim = SimulatedHardware(_pixel_config(tmp_path, "0-0", "1-3"), hw)
    cfg = sim.start()
    svc = Service(cfg, policy=POLICY)
    try:
        n0, n1 = (c.name for c in cfg.controllers)
        assert set(svc.history.run_tables(first["run_id"])) == {n0, n1}  # same names
        out = _run_bundle(svc, "b2", 8100.0)
        assert out["status"] == "ok", out
        own = svc.history.run_tables(out["run_id"])
        assert own[n0].lengths_um.shape == (1, 256) and own[n1].lengths_um.shape == (3, 256)
        for c, bus in zip(cfg.controllers, sim.buses, strict=True):
            active = bus.controllers[0].active_table()
            np.testing.assert_array_equal(active, own[c.name].lengths_um)
            assert table_checksum(active) == out["controller_crcs"][c.name]
    finally:
        svc.shutdown()
        sim.stop()
