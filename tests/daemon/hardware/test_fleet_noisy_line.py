"""On a noisy line (1 % byte errors on the buses' ptys) the fleet's status reads get the
policy's retries instead of the quick probe's, so that noise alone seldom reports a controller
as not answering; the controllers hold their table throughout."""

from __future__ import annotations

import numpy as np

from grassd.daemon.core.hardware.fleet import Fleet
from grassd.firmware_proto.client import RetryPolicy
from grassd.rigs.faults import FaultInjector, FaultPlan


def test_status_reads_on_a_noisy_line_get_more_tries(hw):
    sim, cfg = hw
    policy = RetryPolicy(timeout_s=0.05, retries=2, restarts=2, readback_retries=4)
    with Fleet(cfg.controllers, policy=policy, probe_retries=1) as fleet:
        table = np.full(256, 1234, np.uint16)
        assert all(r.ok for r in fleet.push(table, table_id=7))
        for i, bus in enumerate(sim.buses):
            bus.faults = FaultInjector(FaultPlan(flip=0.004, drop=0.003, duplicate=0.003),
                                       seed=11 + i)
        reports = [r for _ in range(120) for r in fleet.reconcile(table, table_id=7)]
        down = [r for r in reports if not r.reachable]
        assert down, "the noise was too weak to test anything"
        # once the line shows noise, a failed status read has had 1 + policy.retries tries
        late = [r.error for r in down[2:]]
        assert late and all("GET_STATUS failed after 3 tries" in e for e in late), late
        assert len(down) < 0.10 * len(reports)  # 2 tries: about 13 %; 3 tries: about 5 %
        assert all(r.ok for r in reports if r.reachable)  # the table stays on
        assert all(q["recent_failure_rate"] > 0.02 for q in fleet.line_quality().values())
