"""[retention] keeps the ingest journal from growing for ever: rows of archived and rejected
bundles whose directories expired (older than keep_days) are pruned with them, while rows
still "processing" (a bundle waiting for the lux sensor) and the rows of the latest archived /
active table's bundle stay. A re-upload of a bundle that is still journaled is rejected as a
duplicate; one whose row was pruned is processed as new and, its light being older than the
active table's, archived as superseded (an old successful run of the same content is not
taken for its own). In-process daemon, real renders, simulated controllers on ptys, a real
pymodbus lux sensor (stopped, so a bundle without lux waits)."""

from __future__ import annotations

import shutil
import time

from daemon_harness import drop, journal_entry, reported, service, write_config

from grassd.daemon.core.runtime.retention import DAY_S, prune
from grassd.daemon.core.store.history import History
from grassd.daemon.core.store.ingest import Inbox

OLD_LIGHT = [f"2026-03-01T08:{m:02d}:00+01:00" for m in range(10)]


def _names(svc, state: str | None = None) -> set[str]:
    return {j.name for j in svc.history.journal(state)}


def _bad(inbox, name: str) -> None:
    """A bundle whose manifest is invalid: claimed and rejected at once (a journal row)."""
    d = inbox / f".{name}"
    d.mkdir()
    (d / "sky.exr").write_bytes(b"\x76\x2f\x31\x01")
    (d / "manifest.toml").write_text(f'timestamp = 2026-03-01T12:00:00+01:00\n# {name}\n'
                                     'hdri = "sky.exr"\nambient_lux = -5.0\n')
    d.rename(inbox / name)


def test_journal_rows_expire_with_their_bundles(tmp_path, hw):
    sim, cfg = hw
    conf = write_config(tmp_path / "g.toml", tmp_path / "state", cfg,
                        light_extra="lux_wait_s = 600",
                        extra="[retention]\nkeep_days = 1.0\n")
    svc = service(conf, retry_s=600.0, retry_max_s=600.0)
    inbox = svc.cfg.light.inbox
    sim.sensor.stop()  # a bundle without manifest lux waits in processing/

    # ---- old bundles: two applied, ten late uploads of older light, three invalid, one
    # waiting for the lux sensor
    drop(inbox, "early", lux=800.0, timestamp="2026-03-01T07:00:00+01:00")
    svc.tick()
    drop(inbox, "noon", lux=1000.0, timestamp="2026-03-01T12:00:00+01:00")
    svc.tick()
    noon = svc.history.current_table()
    assert svc.history.run_count("ok") == 2 and noon.light_at is not None
    for i, ts in enumerate(OLD_LIGHT):
        drop(inbox, f"old{i}", lux=900.0 + i, timestamp=ts)
    for i in range(3):
        _bad(inbox, f"bad{i}")
    drop(inbox, "waiting", lux=None, timestamp="2026-03-01T13:00:00+01:00")
    svc.tick()
    assert [w["bundle"] for w in svc.status().to_json()["waiting_bundles"]] == ["waiting"]
    assert _names(svc, "processing") == {"waiting"}
    assert all(j.reason.startswith("superseded: ") for j in svc.history.journal("archived")
               if j.name.startswith("old"))
    assert len(svc.history.journal()) == 16
    mid = time.time()
    time.sleep(0.05)

    # ---- young bundles (after ``mid``)
    for i in range(2):
        drop(inbox, f"young{i}", lux=950.0 + i, timestamp=f"2026-03-01T09:0{i}:00+01:00")
    _bad(inbox, "bad-young")
    svc.tick()
    assert len(svc.history.journal()) == 19
    prune(svc.cfg.state_dir, svc.history, svc.cfg.retention, reports_dir=svc.reports_dir)
    assert len(svc.history.journal()) == 19  # nothing is a day old yet

    # ---- retention a day after ``mid``: the old bundles' directories and rows go
    out = prune(svc.cfg.state_dir, svc.history, svc.cfg.retention, reports_dir=svc.reports_dir,
                now=mid + 1.0 * DAY_S)
    assert _names(svc) == {"noon", "waiting", "young0", "young1", "bad-young"}
    assert _names(svc, "processing") == {"waiting"}  # old, but still processing
    assert out.journal == 14 and len(out.bundles) == 14, out
    assert svc.history.journal_count() == 5 and svc.history.journal_count("processing") == 1
    kept = {p.name.split("-", 1)[1] for p in svc.inbox.archive.iterdir()} | \
        {p.name.split("-", 1)[1] for p in svc.inbox.rejected.iterdir()}
    assert kept == {"noon", "young0", "young1", "bad-young"}
    assert (svc.inbox.processing / svc.history.journal("processing")[0].bundle_id).is_dir()
    assert svc.history.latest_archived().name == "noon"  # the light of scheduled runs
    again = prune(svc.cfg.state_dir, svc.history, svc.cfg.retention,
                  reports_dir=svc.reports_dir, now=mid + 1.0 * DAY_S)
    assert (again.journal, again.bundles) == (0, [])

    # ---- re-uploads
    pushes = len(svc.history.pushes(limit=10_000))
    drop(inbox, "young0", lux=950.0, timestamp="2026-03-01T09:00:00+01:00")  # still journaled
    svc.tick()
    [dup] = [p for p in svc.inbox.rejected.iterdir() if ".dup-" in p.name]
    assert (dup / "reason.txt").read_text().startswith("duplicate: identical content was "
                                                       "already archived as ")
    assert svc.history.journal_count() == 5
    drop(inbox, "old3", lux=903.0, timestamp=OLD_LIGHT[3])  # pruned: new, and superseded
    drop(inbox, "early", lux=800.0, timestamp="2026-03-01T07:00:00+01:00")  # pruned, it ran ok
    svc.tick()
    for name in ("old3", "early"):
        j = journal_entry(svc, name)
        assert j.state == "archived" and j.reason.startswith("superseded: "), j
        assert svc.history.run(j.run_id).status == "superseded"
    assert svc.history.latest_archived().name == "noon"
    assert svc.history.current_table().id == noon.id
    assert reported(svc) == {(noon.table_id, noon.table_crc)}
    assert len(svc.history.pushes(limit=10_000)) == pushes
    svc.shutdown()


def test_prune_journal_rules_on_many_rows(tmp_path):
    """History.prune_journal alone, on 1203 rows (chunked deletes): only final rows updated
    before the cut-off go; processing rows, kept directories and protected hashes stay."""
    with History(tmp_path / "state.db") as h:
        for i in range(1200):
            h.journal_claim(f"h{i:04d}", f"id{i:04d}", f"b{i}")
            h.journal_finish(f"h{i:04d}", "archived" if i % 2 else "rejected", reason="x")
        for i in range(3):
            h.journal_claim(f"p{i}", f"pid{i}", f"p{i}")  # still processing
        cut = time.time() + 1.0
        assert h.prune_journal(cut - 3600.0) == 0  # none that old
        n = h.prune_journal(cut, keep_ids={"id0007", "id0008"}, protect={"h0009"})
        assert n == 1197 and h.journal_count() == 6
        assert {j.bundle_hash for j in h.journal()} == {"h0007", "h0008", "h0009", "p0", "p1",
                                                        "p2"}
        assert h.journal_count("processing") == 3


def test_recovered_reupload_of_a_pruned_bundle_is_not_taken_for_its_old_run(tmp_path):
    """A re-upload of a bundle whose journal row was pruned, claimed and then interrupted by
    a crash, is retried at the next start: the old upload's successful run (still in the
    history) is not mistaken for a run of this one that crashed before its archive move."""
    state = tmp_path / "state"
    with History(state / "state.db") as h:
        inbox = Inbox(tmp_path / "inbox", state, h, settle_s=0)
        drop(inbox.inbox, "sky", lux=700.0)
        [b] = inbox.poll()
        inbox.begin(b)
        run = h.start_run("bundle", bundle_hash=b.hash, light_at=b.manifest.timestamp.timestamp())
        h.finish_run(run, "ok", lengths_um=list(range(256)), table_id=run, table_crc=1)
        inbox.archive_bundle(b, run)
        time.sleep(0.01)
        shutil.rmtree(inbox.archive / b.id)  # as retention removes an expired bundle ...
        assert h.prune_journal(time.time()) == 1  # ... and now its journal row
        drop(inbox.inbox, "sky", lux=700.0)  # the same content again: not a duplicate now
        [again] = inbox.poll()
        assert again.hash == b.hash and h.journal_get(b.hash).state == "processing"
        # the daemon crashes here; the next start recovers processing/
        [retry] = Inbox(tmp_path / "inbox", state, h, settle_s=0).recover()
        assert retry.hash == b.hash and (state / "processing" / retry.id).is_dir()
        assert h.journal_get(b.hash).state == "processing"
        assert h.ok_run_for_bundle(b.hash).id == run  # the old run is still in the history
        assert h.ok_run_for_bundle(b.hash, h.journal_get(b.hash).created_at) is None
