"""Inbox ingest: complete-manifest pickup, atomic moves, rejection reasons, crash recovery."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import OpenEXR
import pytest

from grassd.daemon.core.store.history import History
from grassd.daemon.core.store.ingest import Inbox

MANIFEST = """timestamp = 2026-06-21T12:00:00+02:00
hdri = "sky.exr"
ambient_lux = 12000.0
sun_lux = 30000.0
sun_azimuth_deg = 180.0
sun_elevation_deg = 40.0
"""


def write_exr(path: Path, value: float = 1.0) -> None:
    img = np.full((8, 16, 3), value, np.float32)
    OpenEXR.File({"type": OpenEXR.scanlineimage}, {"RGB": img}).write(str(path))


def make_dir_bundle(inbox: Path, name: str, manifest: str = MANIFEST, value: float = 1.0) -> Path:
    d = inbox / name
    d.mkdir(parents=True)
    write_exr(d / "sky.exr", value)
    (d / "manifest.toml").write_text(manifest)
    return d


class Clock:
    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


@pytest.fixture
def env(tmp_path):
    clock = Clock()
    h = History(tmp_path / "state" / "state.db")
    inbox = Inbox(tmp_path / "inbox", tmp_path / "state", h, settle_s=1.0,
                  incomplete_timeout_s=10.0, clock=clock)
    yield inbox, h, clock
    h.close()


def settle(inbox: Inbox, clock: Clock) -> list:
    """Poll twice, 1.5 s apart on the fake clock (first sighting, then settled)."""
    got = inbox.poll()
    clock.t += 1.5
    return got + inbox.poll()


def test_directory_bundle_waits_for_settle_then_archives(env):
    inbox, h, clock = env
    make_dir_bundle(inbox.inbox, "b1")
    assert inbox.poll() == []  # first sighting: not settled yet
    clock.t += 0.5
    assert inbox.poll() == []
    clock.t += 1.0
    [b] = inbox.poll()
    assert b.dir == inbox.processing / b.id and b.dir.is_dir()
    assert not (inbox.inbox / "b1").exists()
    assert b.manifest.light.ambient_lux == 12000.0 and b.manifest.light.sun_elevation_deg == 40.0
    assert set(b.input_hashes) == {"sky.exr", "manifest.toml"}
    assert h.journal_get(b.hash).state == "processing"
    assert inbox.begin(b) == 1
    dest = inbox.archive_bundle(b, run_id=None)
    assert dest.is_dir() and (dest / "sky.exr").is_file()
    assert h.journal_get(b.hash).state == "archived"
    assert inbox.counts() == {"inbox": 0, "processing": 0, "archive": 1, "rejected": 0}


def test_growing_file_is_not_picked_up(env):
    inbox, _, clock = env
    d = make_dir_bundle(inbox.inbox, "grow")
    assert inbox.poll() == []
    for _ in range(3):  # keeps growing: never settles
        clock.t += 1.5
        with open(d / "sky.exr", "ab") as fh:
            fh.write(b"\0" * 100)
        os.utime(d / "sky.exr")
        assert inbox.poll() == []
    clock.t += 1.5
    assert len(inbox.poll()) == 1


def test_flat_json_bundle(env):
    inbox, _, clock = env
    write_exr(inbox.inbox / "noon.exr")
    (inbox.inbox / "noon.manifest.json").write_text(json.dumps(
        {"timestamp": "2026-06-21T12:00:00Z", "hdri": "noon.exr", "ambient_lux": 900}))
    (inbox.inbox / "unrelated.txt").write_text("left alone")
    [b] = settle(inbox, clock)
    assert sorted(p.name for p in b.dir.iterdir()) == ["manifest.json", "noon.exr"]
    assert sorted(p.name for p in inbox.inbox.iterdir()) == ["unrelated.txt"]


def test_flat_bundle_with_bad_manifest_is_rejected_whole(env):
    """The data files a rejected flat manifest names go to rejected/ with it, not left behind
    in the inbox for ever."""
    inbox, h, clock = env
    write_exr(inbox.inbox / "noon.exr")
    (inbox.inbox / "noon.manifest.json").write_text(json.dumps(
        {"timestamp": "2026-06-21T12:00:00Z", "hdri": "noon.exr", "ambient_lux": -5}))
    (inbox.inbox / "unrelated.txt").write_text("left alone")
    assert settle(inbox, clock) == []
    [rej] = list(inbox.rejected.iterdir())
    assert "ambient_lux: -5 lux is impossible" in (rej / "reason.txt").read_text()
    assert sorted(p.name for p in rej.iterdir()) == ["manifest.json", "noon.exr", "reason.txt"]
    assert sorted(p.name for p in inbox.inbox.iterdir()) == ["unrelated.txt"]


@pytest.mark.parametrize(
    ("setup", "reason"),
    [
        ("lux", "ambient_lux: -5 lux is impossible"),
        ("corrupt", "not an OpenEXR file"),
        ("syntax", "not valid TOML"),
    ],
)
def test_bad_bundles_rejected_with_reason(env, setup, reason):
    inbox, h, clock = env
    if setup == "lux":
        make_dir_bundle(inbox.inbox, "bad", MANIFEST.replace("12000.0", "-5"))
    elif setup == "corrupt":
        d = make_dir_bundle(inbox.inbox, "bad")
        (d / "sky.exr").write_bytes(b"GARBAGE" * 100)
    else:
        make_dir_bundle(inbox.inbox, "bad", MANIFEST + "oops = = 1\n")
    assert settle(inbox, clock) == []
    [rej] = list(inbox.rejected.iterdir())
    assert reason in (rej / "reason.txt").read_text()
    [row] = h.journal("rejected")
    assert reason in row.reason and row.bundle_id == rej.name


def test_incomplete_bundle_waits_then_rejected(env):
    inbox, _, clock = env
    d = inbox.inbox / "half"
    d.mkdir()
    (d / "manifest.toml").write_text(MANIFEST + 'checker_raw = "chart.dng"\ncheck'
                                     'er_corners = [[0, 0], [9, 0], [9, 6], [0, 6]]\n')
    write_exr(d / "sky.exr")
    for _ in range(5):
        assert inbox.poll() == []
        clock.t += 1.5
    assert list(inbox.rejected.iterdir()) == []  # still waiting for chart.dng
    clock.t += 10
    inbox.poll()
    [rej] = list(inbox.rejected.iterdir())
    text = (rej / "reason.txt").read_text()
    assert "missing file(s) chart.dng" in text and "incomplete" in text


def test_duplicate_is_rejected_not_processed_twice(env):
    inbox, _, clock = env
    make_dir_bundle(inbox.inbox, "a")
    [b] = settle(inbox, clock)
    inbox.archive_bundle(b, None)
    make_dir_bundle(inbox.inbox, "a-again")  # same content
    assert settle(inbox, clock) == []
    [rej] = list(inbox.rejected.iterdir())
    assert "duplicate" in (rej / "reason.txt").read_text()


def test_recovery_retries_once_and_never_twice(env, tmp_path):
    inbox, h, clock = env
    make_dir_bundle(inbox.inbox, "a")
    make_dir_bundle(inbox.inbox, "b", value=2.0)
    make_dir_bundle(inbox.inbox, "c", value=3.0)
    got = {b.name: b for b in settle(inbox, clock)}
    assert set(got) == {"a", "b", "c"}
    # "a": crashed mid-run (nothing committed) -> retried.
    inbox.begin(got["a"])
    # "b": run committed, crash before the archive move -> archived, not run again.
    inbox.begin(got["b"])
    r = h.start_run("bundle", bundle_hash=got["b"].hash)
    h.finish_run(r, "ok")
    # "c": crashed three times -> rejected.
    for _ in range(3):
        inbox.begin(got["c"])
    inbox2 = Inbox(inbox.inbox, inbox.state_dir, h, settle_s=1.0, clock=clock)
    retry = inbox2.recover()
    assert [b.name for b in retry] == ["a"]
    assert retry[0].hash == got["a"].hash
    assert h.journal_get(got["b"].hash).state == "archived"
    assert h.journal_get(got["b"].hash).run_id == r
    assert h.journal_get(got["c"].hash).state == "rejected"
    assert "3 attempts" in h.journal_get(got["c"].hash).reason
    assert inbox2.recover() == [retry[0]]  # idempotent until processed
    inbox2.archive_bundle(retry[0], None)
    assert inbox2.recover() == []
    assert inbox2.counts() == {"inbox": 0, "processing": 0, "archive": 2, "rejected": 1}


def test_crash_while_rejecting_a_duplicate_does_not_process_it(env):
    """A crash between moving a duplicate into processing/ and on to rejected/ leaves a
    directory the journal does not know; its content hash is that of a finished bundle, so
    recover() rejects it as a duplicate instead of re-opening (and re-running) the original."""
    inbox, h, clock = env
    make_dir_bundle(inbox.inbox, "a")
    [b] = settle(inbox, clock)
    inbox.archive_bundle(b, None)
    shutil.copytree(inbox.archive / b.id, inbox.processing / f"{b.id}.dup-123")
    assert inbox.recover() == []
    assert h.journal_get(b.hash).state == "archived"
    assert h.journal_get(b.hash).bundle_id == b.id
    assert list(inbox.processing.iterdir()) == []
    [rej] = list(inbox.rejected.iterdir())
    assert "duplicate" in (rej / "reason.txt").read_text()


def test_half_moved_flat_bundle_goes_back(env):
    inbox, h, clock = env
    write_exr(inbox.inbox / "x.exr")
    (inbox.inbox / "x.manifest.toml").write_text(MANIFEST.replace("sky.exr", "x.exr"))
    # Simulate a crash after the journal row and the first rename of a flat-bundle claim.
    h.journal_claim("f" * 64, "ffffffffffff-x", "x")
    part = inbox.processing / "ffffffffffff-x.partial"
    part.mkdir()
    os.rename(inbox.inbox / "x.exr", part / "x.exr")
    assert inbox.recover() == []
    assert sorted(p.name for p in inbox.inbox.iterdir()) == ["x.exr", "x.manifest.toml"]
    assert h.journal() == []
    [b] = settle(inbox, clock)
    assert b.name == "x"


@pytest.mark.parametrize("kind", ["dir", "flat"])
def test_bundle_that_cannot_be_moved_stays_in_inbox(env, monkeypatch, kind):
    """rename(2) out of the inbox can fail (e.g. EACCES: a directory written by another user
    without group write, whose '..' cannot be updated). The poll must not raise (that killed
    the daemon at every start), the bundle stays in the inbox untouched with no journal row,
    and it is claimed once the move works."""
    inbox, h, clock = env
    if kind == "dir":
        make_dir_bundle(inbox.inbox, "a")
    else:
        write_exr(inbox.inbox / "x.exr")
        (inbox.inbox / "x.manifest.toml").write_text(MANIFEST.replace("sky.exr", "x.exr"))
    before = sorted(p.name for p in inbox.inbox.rglob("*"))
    real = Inbox._rename
    calls = {"n": 0}

    def failing(src, dst):
        # dir: the bundle's own move fails; flat: the second file (the manifest) fails
        calls["n"] += 1
        if src.parent == inbox.inbox and (kind == "dir" or calls["n"] >= 2):
            raise PermissionError(13, "Permission denied", str(src))
        real(src, dst)

    monkeypatch.setattr(Inbox, "_rename", staticmethod(failing))
    assert settle(inbox, clock) == []
    assert sorted(p.name for p in inbox.inbox.rglob("*")) == before
    assert h.journal() == [] and list(inbox.processing.iterdir()) == []
    monkeypatch.setattr(Inbox, "_rename", staticmethod(real))
    clock.t += 600
    assert len(settle(inbox, clock)) == 1


CRASHER = """
import os, sys
from pathlib import Path
from grassd.daemon.core.store.history import History
from grassd.daemon.core.store.ingest import Inbox
state = Path(sys.argv[1]); h = History(state / "state.db")
inbox = Inbox(Path(sys.argv[2]), state, h, settle_s=0)
for b in inbox.recover() + inbox.poll():
    inbox.begin(b)
    r = h.start_run("bundle", bundle_hash=b.hash)
    if b.name == sys.argv[3]:
        os.kill(os.getpid(), 9)            # die mid-run
    h.finish_run(r, "ok")
    inbox.archive_bundle(b, r)
print("done")
"""


def test_sigkill_mid_run_loses_nothing(tmp_path):
    """Real processes: one dies (SIGKILL) mid-run; the next run finishes every bundle once."""
    state, ibox = tmp_path / "state", tmp_path / "inbox"
    for i, n in enumerate(["p", "q", "r"]):
        make_dir_bundle(ibox, n, value=float(i + 1))
    p1 = subprocess.run([sys.executable, "-c", CRASHER, str(state), str(ibox), "q"])
    assert p1.returncode == -9
    p2 = subprocess.run([sys.executable, "-c", CRASHER, str(state), str(ibox), "-"],
                        capture_output=True, text=True)
    assert p2.stdout.strip() == "done", p2.stderr
    h = History(state / "state.db")
    assert sorted(j.name for j in h.journal("archived")) == ["p", "q", "r"]
    ok = [r for r in h.runs() if r.status == "ok"]
    assert len(ok) == 3 and len({r.bundle_hash for r in ok}) == 3  # each bundle ran OK once
    assert sorted(p.name.split("-", 1)[1] for p in (state / "archive").iterdir()) == ["p", "q", "r"]
    assert list((state / "processing").iterdir()) == []


def test_inbox_on_another_file_system(tmp_path):
    """rename(2) fails with EXDEV across file systems: the bundle is copied, synced, renamed."""
    import tempfile

    shm = Path("/dev/shm")
    if not shm.is_dir() or os.stat(shm).st_dev == os.stat(tmp_path).st_dev:
        pytest.skip("no second file system (/dev/shm) to put the inbox on")
    other = Path(tempfile.mkdtemp(dir=shm))
    try:
        h = History(tmp_path / "state" / "s.db")
        clock = Clock()
        inbox = Inbox(other / "inbox", tmp_path / "state", h, settle_s=1.0, clock=clock)
        make_dir_bundle(inbox.inbox, "far")
        write_exr(inbox.inbox / "flat.exr", 2.0)
        (inbox.inbox / "flat.manifest.toml").write_text(MANIFEST.replace("sky.exr", "flat.exr"))
        got = sorted(settle(inbox, clock), key=lambda b: b.name)
        assert [b.name for b in got] == ["far", "flat"]
        assert list(inbox.inbox.iterdir()) == []
        for b in got:
            assert os.stat(b.dir).st_dev == os.stat(tmp_path).st_dev
            assert b.manifest.light.hdri.is_file()
        assert not list(inbox.processing.glob(".*"))  # no temporary copies left
        h.close()
    finally:
        shutil.rmtree(other, ignore_errors=True)
