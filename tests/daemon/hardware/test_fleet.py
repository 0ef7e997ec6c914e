"""Pushing tables to simulated controllers on real ptys, and reconciling after an unplug."""

from __future__ import annotations

import time

import numpy as np

from grassd.daemon.core.config.settings import load_default_config
from grassd.daemon.core.hardware.fleet import Fleet, table_checksum
from grassd.firmware_proto.client import RetryPolicy
from grassd.rigs.simulated_site import SimulatedHardware

TABLE_A = np.linspace(0, 20000, 256).astype(np.uint16)
TABLE_B = (np.linspace(0, 1, 256) ** 0.7 * 20000).astype(np.uint16)


def test_push_all_then_idempotent(hw):
    sim, cfg = hw
    assert len(sim.buses) == 2 and sim.sensor is not None
    with Fleet(cfg.controllers) as fleet:
        first = fleet.push(TABLE_A, table_id=7)
        assert [r.ok and r.pushed for r in first] == [True, True]
        assert {r.table_crc for r in first} == {table_checksum(TABLE_A)}
        again = fleet.push(TABLE_A, table_id=7)
        assert [(r.ok, r.pushed) for r in again] == [(True, False), (True, False)]
        for bus in sim.buses:
            [dev] = bus.controllers
            assert np.array_equal(dev.active_table().ravel(), TABLE_A)


def test_unplugged_controller_is_reconciled_when_back(hw):
    sim, cfg = hw
    policy = RetryPolicy(timeout_s=0.1, retries=1, restarts=1, readback_retries=2)
    with Fleet(cfg.controllers, policy=policy) as fleet:
        fleet.push(TABLE_A, table_id=1)
        sim.buses[1].unplug(down_s=1.0)
        t0 = time.monotonic()
        res = fleet.push(TABLE_B, table_id=2)
        took = time.monotonic() - t0
        assert [r.ok for r in res] == [True, False]
        assert res[1].reachable is False and "serial port" in res[1].error
        # the unplugged controller still holds table A (atomic banks), the other has B
        assert np.array_equal(sim.buses[0].controllers[0].active_table().ravel(), TABLE_B)
        assert np.array_equal(sim.buses[1].controllers[0].active_table().ravel(), TABLE_A)
        deadline = time.monotonic() + 10
        while True:
            res = fleet.reconcile(TABLE_B, table_id=2)
            if all(r.ok for r in res) or time.monotonic() > deadline:
                break
            time.sleep(0.2)
        assert [(r.ok, r.pushed) for r in res] == [(True, False), (True, True)]
        assert np.array_equal(sim.buses[1].controllers[0].active_table().ravel(), TABLE_B)
    print(f"push with one controller unplugged took {took:.2f} s")


def test_tables_survive_simulator_restart(tmp_path):
    cfg0 = load_default_config()
    sim = SimulatedHardware(cfg0, tmp_path / "hw")
    cfg = sim.start()
    with Fleet(cfg.controllers) as fleet:
        fleet.push(TABLE_B, table_id=9)
    sim.stop()
    sim2 = SimulatedHardware(cfg0, tmp_path / "hw")
    cfg2 = sim2.start()
    try:
        assert [c.port for c in cfg2.controllers] == [c.port for c in cfg.controllers]
        with Fleet(cfg2.controllers) as fleet:
            states = fleet.read_all()
        assert [(s.table_id, s.table_crc) for _, s, _ in states] == \
            [(9, table_checksum(TABLE_B))] * 2
    finally:
        sim2.stop()
