"""Reading what an uploader wrote: only regular files with one name, within the caps, never a
blocking open; a manifest is parsed once while it does not change."""

from __future__ import annotations

import json
import os
import threading

import pytest
from test_ingest import MANIFEST, Clock, make_dir_bundle, write_exr

from grassd.daemon.core.config.limits import BundleLimits
from grassd.daemon.core.store import ingest
from grassd.daemon.core.store.history import History
from grassd.daemon.core.store.ingest import Inbox
from grassd.daemon.core.store.untrusted import UntrustedFileError, read_regular, sha256_regular


def _in_thread(fn, timeout_s: float = 5.0):
    """Run ``fn`` in a thread; fail (instead of hanging) when it does not return in time."""
    out: dict = {}

    def target():
        try:
            out["value"] = fn()
        except BaseException as exc:  # noqa: BLE001 - handed to the test
            out["error"] = exc

    t = threading.Thread(target=target, daemon=True)
    t.start()
    t.join(timeout_s)
    assert not t.is_alive(), f"{fn} blocked for {timeout_s} s"
    if "error" in out:
        raise out["error"]
    return out["value"]


def test_fifo_is_refused_without_blocking(tmp_path):
    os.mkfifo(tmp_path / "f")  # no writer: a plain open() would block for ever
    with pytest.raises(UntrustedFileError, match="FIFO"):
        _in_thread(lambda: read_regular(tmp_path / "f", 1024))


def test_symlink_to_dev_zero_is_refused(tmp_path):
    os.symlink("/dev/zero", tmp_path / "z")
    with pytest.raises(UntrustedFileError, match="symbolic link"):
        _in_thread(lambda: read_regular(tmp_path / "z", 1024))


def test_caps_and_hard_links(tmp_path):
    (tmp_path / "a").write_bytes(b"x" * 100)
    assert read_regular(tmp_path / "a", 100) == b"x" * 100
    with pytest.raises(UntrustedFileError, match="100 bytes, over the cap of 99"):
        read_regular(tmp_path / "a", 99)
    os.link(tmp_path / "a", tmp_path / "b")
    with pytest.raises(UntrustedFileError, match="hard link"):
        sha256_regular(tmp_path / "b", 1000)


@pytest.fixture
def env(tmp_path):
    clock = Clock()
    h = History(tmp_path / "state" / "state.db")
    inbox = Inbox(tmp_path / "inbox", tmp_path / "state", h, settle_s=1.0,
                  incomplete_timeout_s=600.0, clock=clock,
                  limits=BundleLimits(manifest_kib=4, file_mib=1, bundle_mib=2, entries=8))
    yield inbox, h, clock
    h.close()


def test_manifest_waiting_for_its_files_is_parsed_once(env, monkeypatch):
    inbox, _, clock = env
    calls = []
    real = ingest.read_manifest_text
    monkeypatch.setattr(ingest, "read_manifest_text",
                        lambda *a, **kw: calls.append(a) or real(*a, **kw))
    d = inbox.inbox / "waiting"
    d.mkdir(parents=True)
    (d / "manifest.toml").write_text(MANIFEST)  # names sky.exr, which never arrives
    for _ in range(20):
        assert inbox.poll() == []
        clock.t += 1.0
    assert len(calls) == 1
    (d / "manifest.toml").write_text(MANIFEST + "# changed\n")  # a new size: parsed again
    inbox.poll()
    assert len(calls) == 2


def test_bundle_over_the_caps_is_rejected_with_the_reason(env):
    inbox, h, clock = env
    d = make_dir_bundle(inbox.inbox, "big")
    (d / "extra.bin").write_bytes(os.urandom(1536 * 1024))  # over file_mib = 1
    inbox.poll()
    clock.t += 1.5
    assert inbox.poll() == []
    [row] = h.journal("rejected")
    assert "extra.bin has 1572864 bytes, over the cap of 1048576" in row.reason


def test_one_bundle_that_breaks_the_parser_does_not_stop_the_scan(env, monkeypatch):
    inbox, h, clock = env
    make_dir_bundle(inbox.inbox, "a-bad")
    make_dir_bundle(inbox.inbox, "b-good", value=2.0)
    real = ingest.parse_manifest

    def parse(data, base, tz):
        if base.name == "a-bad":
            raise RecursionError("maximum recursion depth exceeded")
        return real(data, base, tz)

    monkeypatch.setattr(ingest, "parse_manifest", parse)
    inbox.poll()
    clock.t += 1.5
    [good] = inbox.poll()
    assert good.name == "b-good"
    [row] = h.journal("rejected")
    assert row.name == "a-bad" and "RecursionError" in row.reason


def test_recover_quarantines_the_bundle_it_cannot_handle(env, monkeypatch):
    inbox, h, clock = env
    for name in ("first", "second"):
        make_dir_bundle(inbox.inbox, name, value=1.0 if name == "first" else 3.0)
    inbox.poll()
    clock.t += 1.5
    assert len(inbox.poll()) == 2
    real = inbox._load_claimed

    def load(d, bid, name, hsh):
        if name == "first":
            raise RuntimeError("a bug met on one bundle")
        return real(d, bid, name, hsh)

    monkeypatch.setattr(inbox, "_load_claimed", load)
    [again] = inbox.recover()  # a restart: both still in processing/
    assert again.name == "second"
    [row] = h.journal("rejected")
    assert row.name == "first" and "could not be recovered" in row.reason
    assert "RuntimeError: a bug met on one bundle" in row.reason


def test_flat_bundle_files_are_named_after_it(env):
    inbox, h, clock = env
    write_exr(inbox.inbox / "x.exr")
    write_exr(inbox.inbox / "x.y.exr", 2.0)
    (inbox.inbox / "x.manifest.toml").write_text(MANIFEST.replace("sky.exr", "x.exr"))
    (inbox.inbox / "x.y.manifest.toml").write_text(MANIFEST.replace("sky.exr", "x.y.exr")
                                                   + "# the second\n")
    inbox.poll()
    clock.t += 1.5
    assert sorted(b.name for b in inbox.poll()) == ["x", "x.y"]
    write_exr(inbox.inbox / "z.exr", 5.0)  # no bundle's: "z" has no manifest
    (inbox.inbox / "w.manifest.toml").write_text(MANIFEST.replace("sky.exr", "z.exr"))
    inbox.poll()
    clock.t += 1.5
    assert inbox.poll() == []
    [row] = h.journal("rejected")
    assert row.name == "w" and "w.<something>" in row.reason
    assert (inbox.inbox / "z.exr").exists(), "a file of no bundle of this name was moved"


def test_a_bundle_that_can_be_neither_processed_nor_rejected_waits_in_the_inbox(env,
                                                                                monkeypatch):
    inbox, h, clock = env
    make_dir_bundle(inbox.inbox, "cursed")

    def broken(*a, **kw):
        raise ValueError("a bug met on one bundle")

    monkeypatch.setattr(ingest, "parse_manifest", broken)
    monkeypatch.setattr(h, "journal_claim", broken)
    inbox.poll()
    clock.t += 1.5
    assert inbox.poll() == []  # no exception reaches the main loop
    [problem] = inbox.problems()
    assert "cursed can be neither processed nor rejected" in problem
    assert (inbox.inbox / "cursed").is_dir()


def test_flat_bundle_whose_name_is_not_utf8_takes_its_own_files(env):
    inbox, h, clock = env
    raw = os.fsdecode(b"bad\xffname")  # as os.scandir gives it: a lone surrogate
    write_exr(inbox.inbox / ".sky.exr")  # OpenEXR writes str paths it can encode only
    os.rename(inbox.inbox / ".sky.exr", inbox.inbox / f"{raw}.exr")
    (inbox.inbox / f"{raw}.manifest.json").write_text(json.dumps({
        "timestamp": "2026-06-21T12:00:00+02:00", "hdri": f"{raw}.exr"}))
    inbox.poll()
    clock.t += 1.5
    [b] = inbox.poll()
    assert b.name == "bad\\xffname" and b.id.endswith("-bad_xffname")
    assert sorted(p.name for p in b.dir.iterdir()) == sorted([f"{raw}.exr", "manifest.json"])
    assert list(inbox.inbox.iterdir()) == []
    assert h.journal_get(b.hash).name == "bad\\xffname"
