"""A bundle that arrives after the active table was made, but whose light is OLDER than that
table's (a late upload), is not applied: it is archived as superseded (history row, journal
reason, one log line naming both light times) and nothing is pushed, so the controllers keep
the table made for the newer light. Light as old as the active table's (a corrected re-upload
of the same measurement) is applied; a newer run that was rejected does not count; the very
first bundle is applied whatever its age; bundles arriving together go newest light first;
`grassd calibrate --now` follows the same rules.
In-process daemon, real renders, simulated controllers on ptys, pymodbus lux sensor."""

from __future__ import annotations

import logging
import sqlite3

from click.testing import CliRunner
from daemon_harness import drop, journal_entry, reported, service, truncated_exr, write_config

from grassd.daemon.cli.main import main as cli
from grassd.daemon.core.runtime.service import collect_status
from grassd.daemon.core.store.layout import STATE_DB

NOON = "2026-03-01T12:00:00+01:00"  # 11:00 UTC


def _corrupt(inbox, name: str, timestamp: str) -> None:
    """A bundle whose EXR is cut short after a sound header: its run starts and is rejected by
    the renderer's reader."""
    d = inbox / f".{name}"
    d.mkdir()
    (d / "sky.exr").write_bytes(truncated_exr())
    (d / "manifest.toml").write_text(f'timestamp = {timestamp}\nhdri = "sky.exr"\n'
                                     "ambient_lux = 900.0\n")
    d.rename(inbox / name)


def _assert_superseded(svc, name: str, active, older_utc: str, active_utc: str) -> None:
    """Bundle ``name`` was archived unused against the active run ``active``."""
    j = journal_entry(svc, name)
    assert j.state == "archived" and j.reason.startswith("superseded: "), j
    assert f"its light ({older_utc})" in j.reason and f"the light ({active_utc})" in j.reason
    assert f"run {active.id}" in j.reason and f"table {active.table_id}" in j.reason
    run = svc.history.run(j.run_id)
    assert (run.status, run.bundle_hash, run.table_id, run.error) == (
        "superseded", j.bundle_hash, None, j.reason)
    assert svc.history.pushes(run.id) == []
    assert (svc.inbox.archive / j.bundle_id / "manifest.toml").is_file()
    assert svc.history.current_table().id == active.id
    assert reported(svc) == {(active.table_id, active.table_crc)}


def test_late_upload_of_older_light_is_archived_as_superseded(tmp_path, hw, caplog):
    _, cfg = hw
    svc = service(write_config(tmp_path / "g.toml", tmp_path / "state", cfg))
    inbox = svc.cfg.light.inbox
    # the very first bundle has nothing to be compared with: applied, however old its light
    drop(inbox, "noon", lux=1000.0, timestamp=NOON)
    svc.tick()
    noon = svc.history.current_table()
    assert noon is not None and noon.bundle_hash == journal_entry(svc, "noon").bundle_hash
    assert reported(svc) == {(noon.table_id, noon.table_crc)}
    pushes = len(svc.history.pushes(limit=10_000))

    # a late upload of the 11:00 light, after the noon table went out
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="grassd.daemon.core.runtime.bundle_pipeline"):
        drop(inbox, "late", lux=1500.0, timestamp="2026-03-01T11:00:00+01:00")
        svc.tick()
    _assert_superseded(svc, "late", noon, "2026-03-01T10:00:00+00:00",
                       "2026-03-01T11:00:00+00:00")
    lines = [r.getMessage() for r in caplog.records if "late" in r.getMessage()]
    assert len(lines) == 1 and "2026-03-01T10:00:00+00:00" in lines[0] \
        and "2026-03-01T11:00:00+00:00" in lines[0], lines
    assert len(svc.history.pushes(limit=10_000)) == pushes  # no push at all, no reconcile
    assert svc.history.latest_archived().name == "noon"  # scheduled runs keep noon's light
    # status (live, and from the database alone as `grassd status` without a daemon shows it)
    for st in (svc.status().to_json(), collect_status(svc.history, svc.cfg).to_json()):
        top = st["runs"][0]
        assert (top["status"], top["error"]) == ("superseded", journal_entry(svc, "late").reason)
        assert st["desired_table"]["run_id"] == noon.id and st["health"] == "ok"
        assert st["run_counts"] == {"ok": 1, "rejected": 0, "failed": 0, "superseded": 1}

    # a newer run that was rejected made no table: its light does not count
    _corrupt(inbox, "broken", "2026-03-01T14:00:00+01:00")
    svc.tick()
    assert journal_entry(svc, "broken").state == "rejected"
    assert svc.history.run(journal_entry(svc, "broken").run_id).status == "rejected"
    assert svc.history.current_table().id == noon.id
    drop(inbox, "half-past", lux=1200.0, timestamp="2026-03-01T12:30:00+01:00")
    svc.tick()
    half = svc.history.current_table()
    assert half.id > noon.id and half.bundle_hash == journal_entry(svc, "half-past").bundle_hash
    assert journal_entry(svc, "half-past").reason is None
    assert reported(svc) == {(half.table_id, half.table_crc)}

    # light as old as the active table's: a corrected re-upload of that measurement, applied
    drop(inbox, "half-past-fixed", lux=1250.0, timestamp="2026-03-01T12:30:00+01:00")
    svc.tick()
    fixed = svc.history.current_table()
    assert fixed.id > half.id and abs(fixed.lux - 1250.0) < 1e-9
    assert reported(svc) == {(fixed.table_id, fixed.table_crc)}

    # a database from before runs.light_at: the active run's light time comes from its
    # archived bundle's manifest
    svc.history._db.execute("UPDATE runs SET light_at = NULL")
    drop(inbox, "older", lux=1100.0, timestamp="2026-03-01T12:29:59+01:00")
    svc.tick()
    _assert_superseded(svc, "older", svc.history.run(fixed.id), "2026-03-01T11:29:59+00:00",
                       "2026-03-01T11:30:00+00:00")

    # a backlog arriving in one pass goes newest light first: one calibration, one push
    runs = svc.history.run_count()
    drop(inbox, "b1300", lux=1300.0, timestamp="2026-03-01T13:00:00+01:00")
    drop(inbox, "b1400", lux=1400.0, timestamp="2026-03-01T14:00:00+01:00")
    drop(inbox, "b1330", lux=1330.0, timestamp="2026-03-01T13:30:00+01:00")
    svc.tick()
    last = svc.history.current_table()
    assert last.bundle_hash == journal_entry(svc, "b1400").bundle_hash
    assert svc.history.run_count() == runs + 3 and svc.history.run_count("ok") == 4
    _assert_superseded(svc, "b1300", last, "2026-03-01T12:00:00+00:00",
                       "2026-03-01T13:00:00+00:00")
    _assert_superseded(svc, "b1330", last, "2026-03-01T12:30:00+00:00",
                       "2026-03-01T13:00:00+00:00")
    svc.shutdown()


def test_calibrate_now_supersedes_older_light_in_the_inbox(tmp_path, hw):
    """`grassd calibrate --now` without a daemon takes the bundles waiting in the inbox like
    the daemon does, so the same rule holds: older light is archived as superseded and the
    command fails with the reason (exit 2); the controllers keep their table."""
    _, cfg = hw
    conf = write_config(tmp_path / "g.toml", tmp_path / "state", cfg)
    svc = service(conf)
    drop(svc.cfg.light.inbox, "noon", lux=1000.0, timestamp=NOON)
    svc.tick()
    noon = svc.history.current_table()
    svc.shutdown()

    drop(svc.cfg.light.inbox, "morning", lux=900.0, timestamp="2026-03-01T09:00:00+01:00")
    r = CliRunner().invoke(cli, ["calibrate", "--now", "--config", str(conf)])
    assert r.exit_code == 2, r.output
    assert "one-shot run superseded: superseded: its light (2026-03-01T08:00:00+00:00) is " \
           "older than the light (2026-03-01T11:00:00+00:00)" in r.output
    db = sqlite3.connect(tmp_path / "state" / STATE_DB)
    try:
        (run_id, status, table_id), = db.execute(
            "SELECT id, status, table_id FROM runs WHERE id > ?", (noon.id,)).fetchall()
        assert (status, table_id) == ("superseded", None)
        assert db.execute("SELECT COUNT(*) FROM pushes WHERE run_id = ?",
                          (run_id,)).fetchone() == (0,)
        assert db.execute("SELECT state, substr(reason, 1, 12) FROM journal WHERE name = "
                          "'morning'").fetchone() == ("archived", "superseded: ")
    finally:
        db.close()
    svc = service(conf)
    assert svc.history.current_table().id == noon.id
    assert reported(svc) == {(noon.table_id, noon.table_crc)}
    svc.shutdown()

    # two bundles waiting: the newest makes the table, the older is superseded, exit 0
    drop(svc.cfg.light.inbox, "b1300", lux=1300.0, timestamp="2026-03-01T13:00:00+01:00")
    drop(svc.cfg.light.inbox, "b1400", lux=1400.0, timestamp="2026-03-01T14:00:00+01:00")
    r = CliRunner().invoke(cli, ["calibrate", "--now", "--config", str(conf)])
    assert r.exit_code == 0 and "one-shot run" in r.output, r.output
    svc = service(conf)
    cur = svc.history.current_table()
    assert cur.id > noon.id and abs(cur.lux - 1400.0) < 1e-9
    assert [r.status for r in svc.history.runs(2)] == ["superseded", "ok"]
    assert reported(svc) == {(cur.table_id, cur.table_crc)}
    svc.shutdown()
