"""A crash between the two steps of archiving a superseded bundle (the directory moved to
archive/, the journal row not yet finished) must not turn it into an ordinary archived bundle:
scheduled runs take their light from the latest archived bundle that a run used, and a
superseded bundle's light is older than the active table's. Real Inbox and History on disk,
no renders."""

from __future__ import annotations

import time

from daemon_harness import drop

from grassd.daemon.core.store.history import History
from grassd.daemon.core.store.ingest import Inbox


def test_recovery_keeps_a_superseded_bundle_superseded(tmp_path):
    state = tmp_path / "state"
    with History(state / "state.db") as h:
        inbox = Inbox(tmp_path / "inbox", state, h, settle_s=0)
        drop(inbox.inbox, "noon", timestamp="2026-03-01T12:00:00+01:00")
        [noon] = inbox.poll()
        inbox.begin(noon)
        run = h.start_run("bundle", bundle_hash=noon.hash,
                          light_at=noon.manifest.timestamp.timestamp())
        h.finish_run(run, "ok", lengths_um=list(range(256)), table_id=run, table_crc=1)
        inbox.archive_bundle(noon, run)
        time.sleep(0.01)

        drop(inbox.inbox, "late", timestamp="2026-03-01T11:00:00+01:00")
        [late] = inbox.poll()
        why = "superseded: its light is older than the active table's"
        sup = h.start_run("bundle", bundle_hash=late.hash,
                          light_at=late.manifest.timestamp.timestamp())
        h.finish_run(sup, "superseded", error=why)
        late.dir.rename(inbox.archive / late.id)  # archive_bundle's first step; then a crash

        assert Inbox(tmp_path / "inbox", state, h, settle_s=0).recover() == []
        row = h.journal_get(late.hash)
        assert row.state == "archived" and row.run_id == sup, row
        assert row.reason == why, row
        assert h.latest_archived().name == "noon"  # scheduled runs keep the newer light
