"""`grassd status --json` keeps its keys (operators' scripts read them): the same keys in the
same order, at every level, from the state database alone and from a running daemon; and the
JSON reads back into the same status.

The key lists below are the wire format. Add a key here only when one is added on purpose;
never rename one."""

from __future__ import annotations

import json

from daemon_harness import after_first_bundle
from status_samples import controller, daemon_state, status, waiting

from grassd.daemon.cli.run import print_status
from grassd.daemon.core.monitoring.status_types import (
    ComputeWait,
    ErrorSeen,
    PushRetry,
    RunSummary,
    Status,
)
from grassd.daemon.core.runtime.service import collect_status
from grassd.daemon.core.store.quarantine import QuarantinedBundle

#: without a daemon (from the state database alone)
DB_KEYS = ["desired_table", "controllers", "runs", "run_counts", "quarantined", "state_dir",
           "running", "health"]
#: what a running daemon adds, after those
LIVE_KEYS = [*DB_KEYS, "pid", "version", "activity", "started_at", "uptime_s", "config",
             "reload_error", "inbox", "rss_mb", "last_error", "last_error_seen",
             "inbox_problems", "metrics_textfile", "status_page", "capture", "lines",
             "waiting_bundles", "compute_wait", "content"]
DESIRED_KEYS = ["table_id", "table_crc", "run_id", "per_controller"]
CONTROLLER_KEYS = ["name", "port", "address", "reachable", "table_id", "table_crc",
                   "desired_crc", "in_sync", "last_seen", "error"]
LIVE_CONTROLLER_KEYS = [*CONTROLLER_KEYS, "push_retry"]
PUSH_RETRY_KEYS = ["failures", "since", "delay_s", "retry_in_s", "error"]
RUN_KEYS = ["id", "trigger", "status", "started_at", "finished_at", "lux", "lux_source",
            "error", "r2", "max_dev_de00", "report", "plot"]
RUN_COUNT_KEYS = ["ok", "rejected", "failed", "superseded"]
QUARANTINED_KEYS = ["bundle", "name", "attempts", "since", "reason"]
WAITING_KEYS = ["bundle", "id", "reason", "since", "retry_in_s"]
COMPUTE_WAIT_KEYS = ["trigger", "reason", "since", "attempts", "retry_in_s"]
ERROR_SEEN_KEYS = ["at", "error", "cleared_at"]
INBOX_KEYS = ["inbox", "processing", "archive", "rejected"]


def _wire(st: Status) -> dict:
    """The status as the control socket sends it and a client reads it."""
    return json.loads(json.dumps(st.to_json(), default=str))


def _full() -> Status:
    """A live status with every optional part present."""
    return status(
        controller("bus0#1", in_sync=False, table_id=2, error="timeout",
                   push_retry=PushRetry(failures=2, since=1.0, delay_s=4.0, retry_in_s=3.0,
                                        error="timeout")),
        controller("bus1#1"),
        runs=(RunSummary(id=1, trigger="bundle", status="ok", started_at=1.0,
                         finished_at=2.0, lux=900.0, lux_source="manifest", error=None,
                         r2=0.99, max_dev_de00=0.5, report="r.json", plot="p.png"),),
        quarantined=(QuarantinedBundle(bundle="b-1", name="b", attempts=3, since=5.0,
                                       reason="interrupted"),),
        daemon=daemon_state(
            inbox={"inbox": 1, "processing": 0, "archive": 2, "rejected": 0},
            last_error_seen=ErrorSeen(at="2026-06-21T12:00:00+00:00", error="disk full",
                                      cleared_at=None),
            waiting_bundles=(waiting("b2", "lux sensor silent", 9.0),),
            compute_wait=ComputeWait(trigger="interval", reason="cannot reach the Dask "
                                     "scheduler", since=4.0, attempts=2, retry_in_s=60.0),
            capture={"camera": "http://cam", "interval_s": 600.0, "captures": 2,
                     "last_at": 3.0, "last_success_at": 3.0, "last_bundle": "b2",
                     "last_error": None, "next_in_s": 500.0}))


def test_every_key_at_every_level():
    js = _wire(_full())
    assert list(js) == LIVE_KEYS
    assert list(js["desired_table"]) == DESIRED_KEYS
    assert [list(c) for c in js["controllers"]] == [LIVE_CONTROLLER_KEYS] * 2
    assert list(js["controllers"][0]["push_retry"]) == PUSH_RETRY_KEYS
    assert js["controllers"][1]["push_retry"] is None
    assert [list(r) for r in js["runs"]] == [RUN_KEYS]
    assert list(js["run_counts"]) == RUN_COUNT_KEYS
    assert [list(q) for q in js["quarantined"]] == [QUARANTINED_KEYS]
    assert [list(w) for w in js["waiting_bundles"]] == [WAITING_KEYS]
    assert list(js["last_error_seen"]) == ERROR_SEEN_KEYS
    assert list(js["compute_wait"]) == COMPUTE_WAIT_KEYS
    assert js["running"] is True and js["health"] == (
        "degraded: controller bus0#1 out of sync (table 2, not 3): timeout; bundle b2 waits: "
        "lux sensor silent; interval run waits for compute (2 failed, retry in 60 s): cannot "
        "reach the Dask scheduler")
    db = _wire(status(controller("bus0#1")))  # no daemon: no live key, no push_retry
    assert list(db) == DB_KEYS and list(db["controllers"][0]) == CONTROLLER_KEYS
    assert db["running"] is False and db["health"] == "ok"


def test_the_json_reads_back_into_the_same_status():
    for st in (_full(), status(controller("bus0#1")), status(table_id=None)):
        back = Status.from_json(_wire(st))
        assert back == st and back.health == st.health
        assert _wire(back) == _wire(st)


def test_keys_a_newer_daemon_adds_are_left_out():
    js = _wire(_full())
    js["new_key"] = 1
    js["controllers"][0]["new_key"] = 2
    assert Status.from_json(js) == _full()


def test_a_status_from_a_daemon_before_compute_wait_reads():
    js = _wire(_full())
    del js["compute_wait"]
    assert Status.from_json(js).daemon.compute_wait is None


def test_a_daemon_and_the_database_give_these_keys(tmp_path, hw):
    """Built by the code that builds it: a real daemon (simulated hardware) after its first
    run, and the state database alone."""
    sim, cfg = hw
    svc, _ = after_first_bundle(tmp_path, cfg)
    try:
        live = _wire(svc.status())
        db = _wire(collect_status(svc.history, svc.cfg))
    finally:
        svc.shutdown()
    assert list(live) == LIVE_KEYS and list(db) == DB_KEYS
    assert list(live["desired_table"]) == DESIRED_KEYS
    assert all(list(c) == LIVE_CONTROLLER_KEYS for c in live["controllers"])
    assert all(list(c) == CONTROLLER_KEYS for c in db["controllers"])
    assert all(list(r) == RUN_KEYS for r in live["runs"]) and live["runs"]
    assert list(live["run_counts"]) == RUN_COUNT_KEYS and list(live["inbox"]) == INBOX_KEYS
    assert live["health"] == db["health"] == "ok" and live["running"] and not db["running"]
    assert Status.from_json(live).to_json() == live


def test_grassd_status_prints_the_status_verdict():
    """One verdict: the health line and every controller's word come from the status
    (:func:`assess`, :attr:`ControllerStatus.state`), as on the page, metrics and alerts."""
    st = _full()
    lines: list[str] = []
    print_status(st, echo=lines.append)
    assert f"health: {st.health.summary()}" in lines
    assert "  bus0#1: table 2, out of sync  (timeout); 2 failed push(es), next attempt in 3 s" \
        in lines
    assert "  bus1#1: table 3, in sync" in lines
    assert ("interval run waits for compute (2 failed, retry in 60 s): cannot reach the Dask "
            "scheduler") in lines
