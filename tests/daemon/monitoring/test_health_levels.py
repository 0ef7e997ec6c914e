"""Health levels (ok, degraded, failed) from a daemon status as collect_status writes it."""

from __future__ import annotations

from status_samples import controller, daemon_state, status, waiting

from grassd.daemon.core.monitoring.health import assess
from grassd.daemon.core.monitoring.status_types import RunCounts, Status


def status_of(*in_sync: bool, reachable: bool = True, table: bool = True, **live) -> Status:
    ctrls = [controller(f"/dev/ttyACM{i}#1", reachable=reachable or ok, in_sync=ok,
                        table_id=3 if ok else 2, error=None if ok else "timeout")
             for i, ok in enumerate(in_sync)]
    return status(*ctrls, table_id=3 if table else None,
                  daemon=daemon_state(**live) if live else None)


def test_levels():
    assert assess(status_of(True, True)).level == "ok" and assess(status_of(True)).reasons == ()
    h = assess(status_of(True, False, reachable=False))
    assert h.level == "degraded" and h.severity == 1
    assert h.reasons == ("controller /dev/ttyACM1#1 unreachable (table 2, not 3): timeout",)
    h = assess(status_of(False, False))
    assert h.level == "failed" and h.severity == 2 and len(h.reasons) == 2
    assert "out of sync" in h.reasons[0]


def test_no_table():
    assert assess(status_of(table=False)).reasons == ("no table yet",)
    st = status(table_id=None, run_counts=RunCounts(ok=0, failed=2, rejected=1))
    h = assess(st)
    assert h.level == "failed" and h.reasons == ("no table: all 3 run(s) so far failed or were "
                                                 "rejected",)


def test_errors_and_waiting_bundles_degrade():
    assert assess(status_of(True, last_error="disk full")).level == "degraded"
    assert assess(status_of(True, reload_error="bad key")).reasons == (
        "reload refused: bad key",)
    h = assess(status_of(True, waiting_bundles=(waiting("b1", "lux sensor silent"),)))
    assert h.reasons == ("bundle b1 waits: lux sensor silent",)
    h = assess(status_of(False, last_error="disk full"))  # failed wins, every reason kept
    assert h.level == "failed" and h.reasons[-1] == "error: disk full"


def test_summary_is_the_status_health_line():
    """`grassd status` prints ``health`` as the level and its reasons, one line: the same
    verdict as the alerts, metrics and status page."""
    assert assess(status_of(True, True)).summary() == "ok"
    assert assess(status_of(table=False)).summary() == "degraded: no table yet"
    assert assess(status_of(True, False, last_error="disk full")).summary() == (
        "degraded: controller /dev/ttyACM1#1 out of sync (table 2, not 3): timeout; "
        "error: disk full")


def test_a_status_carries_its_verdict():
    """A status computes its ``health`` with :func:`assess` from its own fields: no reader
    can show another verdict, and a changed copy gets its own."""
    import dataclasses

    st = status_of(True, False, last_error="disk full")
    assert st.health == assess(st) and st.to_json()["health"] == st.health.summary()
    fixed = dataclasses.replace(st, controllers=(st.controllers[0],), daemon=None)
    assert fixed.health.level == "ok"
