"""Quarantined bundles (abandoned after repeated interrupted attempts) are listed by
`grassd status` (text and JSON) and `grassd bundles list`, and `grassd bundles retry NAME` puts
one back into the inbox with a fresh attempt count: through the running daemon (`grassd run`
subprocess, control socket), or without a daemon under the state directory's lock. The crash
state is the one three killed daemons leave: the bundle claimed into processing/ with three
attempts counted in the journal."""

from __future__ import annotations

import json
import subprocess

from test_grassd_run_end_to_end import GRASSD, Daemon, manifest, wait_for

from grassd.daemon.core.store.history import History
from grassd.daemon.core.store.ingest import Inbox


def _crashed_three_times(d: Daemon, name: str, i: int) -> None:
    """Leave bundle ``name`` as three daemons killed while processing it leave it."""
    d.drop(name, manifest(i, 3000.0))
    with History(d.state / "state.db") as h:
        inbox = Inbox(d.state / "inbox", d.state, h, settle_s=0)
        [b] = inbox.poll()
        for _ in range(3):
            inbox.begin(b)


def _grassd(d: Daemon, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([GRASSD, *args, "--config", str(d.config)], capture_output=True,
                          text=True, timeout=300)


def _row(d: Daemon, name: str):
    with History(d.state / "state.db") as h:
        return [j for j in h.journal() if j.name == name]


def test_quarantined_bundle_listed_and_retried_through_the_daemon_and_without(tmp_path):
    d = Daemon(tmp_path)
    try:
        _crashed_three_times(d, "poison", 1)
        d.start()  # its recovery quarantines the bundle
        st = json.loads(_grassd(d, "status", "--json").stdout)
        [q] = st["quarantined"]
        assert q["name"] == "poison" and q["attempts"] == 3
        assert q["reason"].startswith("abandoned after 3 attempts")
        assert (d.state / "rejected" / q["bundle"]).is_dir()
        text = _grassd(d, "status").stdout
        assert f"quarantined bundle {q['bundle']} (3 interrupted attempts" in text
        assert f"grassd bundles retry {q['bundle']}" in text
        listed = _grassd(d, "bundles", "list").stdout
        assert listed.startswith(f"{q['bundle']}  poison  3 attempts")

        bad = _grassd(d, "bundles", "retry", "nosuch")
        assert bad.returncode == 2
        assert bad.stderr.strip().splitlines() == [
            f"grassd: error: daemon: no quarantined bundle 'nosuch' (quarantined: "
            f"{q['bundle']}); see `grassd bundles list`"]

        res = _grassd(d, "bundles", "retry", "poison")
        assert res.returncode == 0, res.stderr
        assert res.stdout.startswith(f"the daemon put {q['bundle']} back into the inbox")
        wait_for(lambda: d.status()["run_counts"]["ok"] == 1, 120, "the retried run", d)
        wait_for(lambda: [j.state for j in _row(d, "poison")] == ["archived"], 30,
                 "archived", d)
        [j] = _row(d, "poison")
        assert j.attempts == 1  # counted afresh
        assert d.status()["quarantined"] == []
        wait_for(lambda: d.status()["health"] == "ok", 30, "its table on every controller", d)
        assert _grassd(d, "bundles", "list").stdout.strip() == "no quarantined bundles"
        assert d.stop() == 0

        # without a daemon: the command itself moves it, holding the state lock
        _crashed_three_times(d, "second", 2)
        with History(d.state / "state.db") as h:
            assert Inbox(d.state / "inbox", d.state, h).recover() == []  # as at a start
        [q2] = json.loads(_grassd(d, "bundles", "list", "--json").stdout)
        assert q2["name"] == "second"
        res = _grassd(d, "bundles", "retry", q2["bundle"])
        assert res.returncode == 0, res.stderr
        assert res.stdout.startswith(f"put {q2['bundle']} back into the inbox as "
                                     f"{d.state / 'inbox' / 'second'}")
        assert (d.state / "inbox" / "second" / "manifest.toml").is_file()
        assert not (d.state / "inbox" / "second" / "reason.txt").exists()
        assert not (d.state / "rejected" / q2["bundle"]).exists()
        assert _row(d, "second") == []  # attempts reset: it is a new upload
        d.start()
        wait_for(lambda: d.status()["run_counts"]["ok"] == 2, 120, "the second retried run",
                 d)
        # the run is recorded ok just before its bundle moves to the archive
        wait_for(lambda: [j.state for j in _row(d, "second")] == ["archived"], 30,
                 "archived", d)
    finally:
        d.close()
