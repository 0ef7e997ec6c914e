"""Table pushes under every fault of a serial line: each push ends old-or-new, never mixed.

For each fault kind, 200 pushes (fixed seed) to two controllers sharing one simulated bus on a
real pty: a push that reports success must have made the new table active; a push that reports
failure must have left the old table active; the table a fresh boot would load from the EEPROM
file must be one of the two, bit for bit. A last case combines every fault with per-pixel
tables. Afterwards the faults stop and the same client must
push successfully without any manual recovery.
"""

from __future__ import annotations

import time

import numpy as np
import pytest

from grassd.firmware_proto.client import ControllerClient, RetryPolicy
from grassd.firmware_proto.errors import PushFailed
from grassd.firmware_proto.tables import table_crc
from grassd.rigs.faults import FaultInjector, FaultPlan
from grassd.rigs.push_audit import booted_table
from grassd.rigs.simulator import SimulatedBus, make_controllers

PUSHES = 200

PLANS = {
    "dropped": FaultPlan(drop=0.001),
    "flipped": FaultPlan(flip=0.001),
    "duplicated": FaultPlan(duplicate=0.001),
    "delayed": FaultPlan(delay=0.001, delay_s=(0.005, 0.05)),
    "reboot": FaultPlan(reboot=0.03, torn_write=0.03),
    "unplug": FaultPlan(unplug=0.04, unplug_s=(0.005, 0.04)),
    # everything at once, with per-pixel tables (1 KiB, four chunks per push)
    "combined": FaultPlan(drop=0.0002, flip=0.0002, duplicate=0.0002, delay=0.0002,
                          delay_s=(0.005, 0.03), reboot=0.01, torn_write=0.01, unplug=0.01,
                          unplug_s=(0.005, 0.03)),
}
PER_PIXEL = {"combined": 2}

# Few retries so that some pushes do fail and the failure path is exercised too.
POLICY = RetryPolicy(timeout_s=0.02, retries=1, backoff_s=0.002, backoff_max_s=0.02,
                     restarts=1, readback_retries=12)


@pytest.mark.parametrize("fault", list(PLANS))
def test_pushes_under_faults_end_old_or_new(fault, tmp_path, capsys):
    injector = FaultInjector(PLANS[fault], seed=20261122)
    n_pixels = PER_PIXEL.get(fault, 1)
    shape = (n_pixels, 256) if fault in PER_PIXEL else (256,)
    ctrls = make_controllers(tmp_path, [1, 2], n_pixels=n_pixels)
    rng = np.random.default_rng(7)
    ok = failed = unknown = 0
    t0 = time.perf_counter()
    with SimulatedBus(ctrls, link_path=tmp_path / "tty", faults=injector) as bus, \
            ControllerClient(bus.path, baudrate=921_600, policy=POLICY, seed=3) as client:
        injector.enabled = False
        current = {}
        for a in (1, 2):  # a known starting table on each controller
            current[a] = rng.integers(0, 20001, shape).astype(np.uint16)
            client.push_table(a, current[a], table_id=0)
        injector.enabled = True
        for i in range(PUSHES):
            address = 1 + i % 2
            ctl = ctrls[address - 1]
            old, new = current[address], rng.integers(0, 20001, shape).astype(np.uint16)
            tid = i + 1
            try:
                st = client.push_table(address, new, table_id=tid)
            except PushFailed as exc:
                truth = booted_table(ctl)
                assert np.array_equal(truth, old), f"push {i} failed but the old table is gone"
                assert np.array_equal(ctl.active_table(), old)
                if exc.active is None:
                    unknown += 1
                else:
                    assert exc.active.table_crc == table_crc(old)
                failed += 1
                continue
            assert (st.table_id, st.table_crc) == (tid, table_crc(new))
            assert np.array_equal(booted_table(ctl), new), f"push {i}: success not persisted"
            assert np.array_equal(ctl.active_table(), new)
            current[address] = new
            ok += 1
        elapsed = time.perf_counter() - t0
        counts = injector.counts
        assert bus.errors == 0
        # the bus heals by itself: same client, same port name, no manual reset
        injector.enabled = False
        final = rng.integers(0, 20001, shape).astype(np.uint16)
        for a in (1, 2):
            assert client.push_table(a, final, table_id=999).table_crc == table_crc(final)
            assert np.array_equal(ctrls[a - 1].active_table(), final)
        with capsys.disabled():
            print(f"\n[{fault}] {PUSHES} pushes: {ok} ok, {failed} failed ({unknown} unknown), "
                  f"faults injected {counts.total()} ({counts}), retransmissions "
                  f"{client.retransmissions}, reopens {client.link.opens - 1}, "
                  f"bad frames host/bus {client.link.reader.stats.bad}/{bus.reader.stats.bad}, "
                  f"{elapsed / PUSHES * 1e3:.1f} ms/push")
    assert ok + failed == PUSHES
    assert counts.total() >= 20, "the fault was hardly injected: the test would prove nothing"
    assert ok >= PUSHES // 2, f"only {ok} of {PUSHES} pushes succeeded"
    assert unknown == 0
