"""Whatever an uploader puts in the inbox, a running `grassd run` rejects the bundle with a
reason, goes on to process the valid bundle dropped after it, and starts again on the same state
directory. Each attack (rigs/inbox_fuzz.py) was proven to stop, block or exhaust the
daemon before.

One real daemon process serves the module (simulated controllers on ptys, a Modbus lux sensor on
127.0.0.1); every wait is bounded, so a daemon that blocks fails the test instead of hanging CI.
"""

from __future__ import annotations

import json
import os
import shutil

import pytest
from daemon_harness import SITE
from test_grassd_run_end_to_end import Daemon, manifest, wait_for

from grassd.rigs.inbox_fuzz import ATTACKS, drop_attack

#: seconds a rejection or a valid bundle's calibration may take on a loaded 2-core CI machine
WAIT_S = 90.0

_counter = iter(range(100, 10_000))


def _valid_after(d: Daemon) -> None:
    """Drop a valid bundle (light newer than any before) and wait until it is archived."""
    i = next(_counter)
    name = f"valid{i}"
    d.drop(name, manifest(i, lux=3000.0))
    wait_for(lambda: any(p.name.endswith(f"-{name}") for p in (d.state / "archive").iterdir()),
             WAIT_S, f"valid bundle {name} archived after the hostile one", d)


def _rejected_reason(d: Daemon, name: str) -> str:
    """Wait until bundle ``name`` is in rejected/ with a reason.txt; return the reason."""
    def found():
        for p in (d.state / "rejected").iterdir():
            if p.name.split("-", 1)[-1] == name and (p / "reason.txt").is_file():
                return (p / "reason.txt").read_text()
        return None
    return wait_for(found, WAIT_S, f"bundle {name} rejected with a reason", d)


@pytest.fixture(scope="module")
def daemon(tmp_path_factory):
    d = Daemon(tmp_path_factory.mktemp("hostile"))
    d.start()
    yield d
    d.close()


@pytest.mark.parametrize("attack", sorted(ATTACKS))
def test_hostile_bundle_rejected_and_daemon_goes_on(daemon, attack):
    build, word = ATTACKS[attack]
    # light newer than any before, so that the daemon reads the HDRI (older is superseded)
    drop_attack(daemon.state / "inbox", attack, build, manifest(next(_counter), lux=1000.0))
    reason = _rejected_reason(daemon, attack)
    print(f"\n  {attack}: {reason.strip()[:200]}")
    assert word in reason
    _valid_after(daemon)


def test_flat_bundle_may_not_take_another_bundles_file(daemon):
    inbox = daemon.state / "inbox"
    shutil.copy(SITE, inbox / ".other.exr")
    os.rename(inbox / ".other.exr", inbox / "other.exr")  # bundle "other" is still uploading
    (inbox / ".thief.manifest.toml").write_text(manifest(2, lux=1000.0).replace(
        'hdri = "sky.exr"', 'hdri = "other.exr"'))
    os.rename(inbox / ".thief.manifest.toml", inbox / "thief.manifest.toml")
    reason = _rejected_reason(daemon, "thief")
    assert "thief.<something>" in reason
    assert (inbox / "other.exr").is_file(), "another bundle's file was moved"
    _valid_after(daemon)


def test_valid_bundle_with_a_newline_in_its_name_is_processed(daemon):
    name = "evil\nSTATUS=forged\nREADY=1"
    i = next(_counter)
    daemon.drop(name, manifest(i, lux=3000.0))
    wait_for(lambda: any("evil" in p.name for p in (daemon.state / "archive").iterdir()),
             WAIT_S, "the bundle with a newline in its name archived", daemon)
    assert not any("\n" in p.name for p in (daemon.state / "archive").iterdir())
    _valid_after(daemon)


def test_names_that_are_not_utf8_and_lone_surrogates(daemon):
    """A directory name with a byte that is not UTF-8 (a file name decodes it to a lone
    surrogate, which SQLite and reason.txt cannot store) is processed under an escaped name;
    a JSON manifest whose strings hold lone surrogates is rejected with a reason."""
    inbox = os.fsencode(daemon.state / "inbox")
    i = next(_counter)
    tmp = daemon.state / "inbox" / ".bytes"
    tmp.mkdir()
    shutil.copy(SITE, tmp / "sky.exr")
    (tmp / "manifest.toml").write_text(manifest(i, lux=3000.0))
    os.rename(os.fsencode(tmp), inbox + b"/bad\xffname")
    wait_for(lambda: any(p.name.endswith("-bad_xffname") for p in (daemon.state / "archive")
                         .iterdir()), WAIT_S, "the bundle with a non-UTF-8 name archived", daemon)
    tmp = daemon.state / "inbox" / ".surrogates"
    tmp.mkdir()
    shutil.copy(SITE, tmp / "sky.exr")
    (tmp / "manifest.json").write_text(json.dumps({
        "timestamp": "2026-06-21T12:00:00+09:00", "hdri": "\ud800.exr",
        "capture": {"note": "\udcff"}}))
    os.rename(tmp, daemon.state / "inbox" / "surrogates")
    reason = _rejected_reason(daemon, "surrogates")
    assert "\\ud800" in reason
    _valid_after(daemon)


def test_daemon_starts_again_on_the_same_state_directory(daemon):
    """After every attack above (module order: this test runs last), a restart comes up and
    still processes bundles; a bundle stranded in processing/ with a reason.txt directory and
    an unreadable manifest is quarantined by recover(), not a crash loop."""
    d = daemon
    assert d.stop() == 0
    stranded = d.state / "processing" / "0123456789ab-stranded"
    stranded.mkdir()
    (stranded / "reason.txt").mkdir()
    os.mkfifo(stranded / "manifest.toml")
    d.start()
    reason = _rejected_reason(d, "stranded")
    assert "FIFO" in reason or "recovered" in reason
    _valid_after(d)
    st = d.status()
    print("\n  after restart:", json.dumps(st["inbox"]))
    assert st["inbox"]["processing"] == 0
