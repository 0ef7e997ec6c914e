"""Pushes over a line with 1 % byte errors get through (adaptive chunk size) and never corrupt.

The client shrinks its TABLE_CHUNKs after failed ones and grows them back after clean ones
(firmware_proto.line_quality). Every push is audited against the controller's RAM and EEPROM:
old or new table, never a corrupt or mixed one (rigs.push_audit).
"""

from __future__ import annotations

import numpy as np
import pytest

from grassd.firmware_proto.client import ControllerClient, RetryPolicy
from grassd.firmware_proto.line_quality import LineQuality
from grassd.rigs.faults import FaultInjector, FaultPlan
from grassd.rigs.loopback import LoopbackLink
from grassd.rigs.push_audit import audit_pushes
from grassd.rigs.simulator import SimulatedBus, make_controllers

#: 1 % of the bytes damaged in both directions
NOISE = FaultPlan(flip=0.004, drop=0.003, duplicate=0.003)


def _start(client: ControllerClient, injector: FaultInjector,
           shape: tuple[int, ...] = (256,)) -> None:
    """Push a first ("old") table over a healed line, then turn the faults on."""
    injector.enabled = False
    client.push_table(1, np.full(shape, 500, np.uint16), table_id=0)
    injector.enabled = True


def test_line_quality_halves_on_failure_and_doubles_after_clean_chunks():
    q = LineQuality(max_bytes=256, min_bytes=16, grow_after=2, adaptive=True)
    assert q.chunk_size(1016) == 256 and q.chunk_size(100) == 100
    for expected in (128, 64, 32, 16, 16):
        q.note_chunk(False, q.chunk_size(256))
        assert q.chunk_size(256) == expected
    q.note_chunk(True, 16)
    assert q.chunk_size(256) == 16  # one clean chunk is not enough
    q.note_chunk(True, 16)
    assert q.chunk_size(256) == 32
    q.note_chunk(False, 8, tail=True)  # a failed tail still counts as noise
    assert q.chunk_size(256) == 16
    snap = q.snapshot()
    assert snap["smallest_chunk_bytes"] == 16 and snap["shrinks"] == 5 and snap["grows"] == 1
    assert q.noisy() is False  # no request tries counted yet
    for answered in [True] * 97 + [False] * 3:
        q.note_try(answered)
    assert q.noisy() and q.snapshot()["recent_failure_rate"] == 0.03
    fixed = LineQuality(max_bytes=256, min_bytes=16, grow_after=2, adaptive=False)
    fixed.note_chunk(False, 256)
    assert fixed.chunk_size(256) == 256


def test_300_noisy_pushes_with_power_cuts_get_through_and_never_corrupt(tmp_path):
    ctrls = make_controllers(tmp_path, [1])
    injector = FaultInjector(FaultPlan(flip=0.004, drop=0.003, duplicate=0.003,
                                       reboot=0.002, torn_write=0.002), seed=181125)
    client = ControllerClient("loopback", policy=RetryPolicy(backoff_s=0.0), seed=5,
                              link=LoopbackLink(ctrls, injector))
    _start(client, injector)
    audit = audit_pushes(client, ctrls[0], 300, np.random.default_rng(1), first_id=1)
    assert audit.bad == 0, audit.problems
    assert injector.counts.total() > 2000 and injector.counts.reboots > 0
    assert audit.ok >= 290, audit.summary()
    q = client.quality.snapshot()
    assert q["smallest_chunk_bytes"] <= 32 and q["recent_failure_rate"] > 0.1
    # fixed 256-byte chunks on the same line: most pushes fail (this is what adapting fixes)
    fixed = ControllerClient("loopback", policy=RetryPolicy(backoff_s=0.0,
                                                            adaptive_chunks=False),
                             seed=5, link=LoopbackLink(ctrls, injector))
    worse = audit_pushes(fixed, ctrls[0], 40, np.random.default_rng(2), first_id=1000)
    assert worse.bad == 0 and worse.ok < 30, worse.summary()
    for c in ctrls:
        c.close()


@pytest.mark.parametrize("per_pixel", [False, True])
def test_noisy_pty_pushes_succeed_and_the_chunk_grows_back_on_a_clean_line(tmp_path,
                                                                           per_pixel):
    n_pixels = 2 if per_pixel else 1
    shape = (n_pixels, 256) if per_pixel else (256,)
    ctrls = make_controllers(tmp_path, [1], n_pixels=n_pixels)
    injector = FaultInjector(NOISE, seed=4242)
    policy = RetryPolicy(timeout_s=0.03, backoff_s=0.002, backoff_max_s=0.02)
    with SimulatedBus(ctrls, link_path=tmp_path / "tty", faults=injector) as bus, \
            ControllerClient(bus.path, baudrate=921_600, policy=policy, seed=9) as client:
        _start(client, injector, shape)
        audit = audit_pushes(client, ctrls[0], 4, np.random.default_rng(3), shape=shape)
        assert audit.bad == 0, audit.problems
        assert audit.ok == 4, audit.summary()
        assert max(audit.seconds) < 30
        assert client.quality.snapshot()["chunk_bytes"] < 256
        injector.enabled = False  # the cable is fixed: chunks grow back to the limit
        clean = audit_pushes(client, ctrls[0], 3, np.random.default_rng(4), first_id=100,
                             shape=shape)
        assert clean.ok == 3 and clean.bad == 0
        assert client.quality.snapshot()["chunk_bytes"] == 256
        assert bus.errors == 0
