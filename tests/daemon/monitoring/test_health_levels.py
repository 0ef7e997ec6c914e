"""Health levels (ok, degraded, failed) from a daemon status as collect_status writes it."""

from __future__ import annotations

from grassd.daemon.monitoring.health import assess


def status(*in_sync: bool, reachable: bool = True, table: bool = True, **extra) -> dict:
    ctrls = [{"name": f"/dev/ttyACM{i}#1", "reachable": reachable or ok, "in_sync": ok,
              "table_id": 3 if ok else 2, "error": None if ok else "timeout"}
             for i, ok in enumerate(in_sync)]
    return {"desired_table": {"table_id": 3} if table else None, "controllers": ctrls,
            "run_counts": {"ok": int(table), "failed": 0, "rejected": 0}, **extra}


def test_levels():
    assert assess(status(True, True)).level == "ok" and assess(status(True)).reasons == ()
    h = assess(status(True, False, reachable=False))
    assert h.level == "degraded" and h.severity == 1
    assert h.reasons == ("controller /dev/ttyACM1#1 unreachable (table 2, not 3): timeout",)
    h = assess(status(False, False))
    assert h.level == "failed" and h.severity == 2 and len(h.reasons) == 2
    assert "out of sync" in h.reasons[0]


def test_no_table():
    assert assess(status(table=False)).reasons == ("no table yet",)
    st = status(table=False)
    st["run_counts"] = {"ok": 0, "failed": 2, "rejected": 1}
    h = assess(st)
    assert h.level == "failed" and h.reasons == ("no table: all 3 run(s) so far failed or were "
                                                 "rejected",)


def test_errors_and_waiting_bundles_degrade():
    assert assess(status(True, last_error="disk full")).level == "degraded"
    assert assess(status(True, reload_error="bad key")).reasons == ("reload refused: bad key",)
    h = assess(status(True, waiting_bundles=[{"bundle": "b1", "reason": "lux sensor silent"}]))
    assert h.reasons == ("bundle b1 waits: lux sensor silent",)
    h = assess(status(False, last_error="disk full"))  # failed wins, every reason kept
    assert h.level == "failed" and h.reasons[-1] == "error: disk full"


def test_summary_is_the_status_health_line():
    """`grassd status` prints ``health`` as the level and its reasons, one line: the same
    verdict as the alerts, metrics and status page."""
    assert assess(status(True, True)).summary() == "ok"
    assert assess(status(table=False)).summary() == "degraded: no table yet"
    assert assess(status(True, False, last_error="disk full")).summary() == (
        "degraded: controller /dev/ttyACM1#1 out of sync (table 2, not 3): timeout; "
        "error: disk full")
