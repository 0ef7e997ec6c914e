"""A controller whose table pushes keep failing (simulated controller on a pty whose EEPROM
writes are all torn) must not add a history row at every reconcile: its first failure is
recorded, then at most one summary row per failure_row_s, and the recovery again."""

from __future__ import annotations

import time

from daemon_harness import after_first_bundle, drop

from grassd.rigs.faults import FaultInjector, FaultPlan


def test_failing_controller_rows_are_deduplicated(tmp_path, hw):
    sim, cfg = hw
    # push_retry_s=0: no reconcile backoff (test_push_backoff), a push every pass
    svc, first = after_first_bundle(tmp_path, cfg, failure_row_s=5.0, push_retry_s=0.0)
    inbox = svc.cfg.light.inbox
    bad = svc.fleet.controllers[0].name
    injector = FaultInjector(FaultPlan(torn_write=1.0))  # every EEPROM write of bus 0 fails
    sim.buses[0].faults = injector
    for dev in sim.buses[0].controllers:
        dev.eeprom.tear_hook = injector.tear

    drop(inbox, "b2", lux=5000.0)
    svc.tick()
    pushed_at = time.monotonic()
    run2 = svc.history.current_table()
    assert run2.id != first.id

    def rows() -> list:
        return [p for p in svc.history.pushes(run2.id) if p.controller == bad]

    assert [(p.kind, p.ok) for p in rows()] == [("push", False)]
    for _ in range(3):  # the daemon reconciles every 2 s: each one fails again
        reports = svc.reconcile()
        assert [r.ok for r in reports if r.controller == bad] == [False]
    assert len(rows()) == 1  # nothing new within failure_row_s
    st = {c.name: c for c in svc.history.controllers()}[bad]
    assert not (st.reported_id == run2.table_id)  # still reported as not on the table

    time.sleep(max(pushed_at + 5.1 - time.monotonic(), 0))
    svc.reconcile()  # one summary row per interval
    svc.reconcile()
    summary = rows()
    assert [(p.kind, p.ok) for p in summary] == [("push", False), ("reconcile", False)]
    assert "5 failed pushes since" in summary[-1].error and "3 not recorded" in summary[-1].error

    injector.enabled = False  # the controller heals: the recovery is recorded at once
    reports = svc.reconcile()
    assert all(r.ok for r in reports)
    assert [(p.kind, p.ok) for p in rows()] == [("push", False), ("reconcile", False),
                                                ("reconcile", True)]
    injector.enabled = True  # a new streak starts with a row of its own
    drop(inbox, "b3", lux=2000.0)
    svc.tick()
    run3 = svc.history.current_table()
    for _ in range(3):
        svc.reconcile()
    assert [(p.kind, p.ok) for p in svc.history.pushes(run3.id) if p.controller == bad] == \
        [("push", False)]
    svc.shutdown()
