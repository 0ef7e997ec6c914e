"""Whatever an uploader puts in the inbox, a running `grassd run` rejects the bundle with a
reason, goes on to process the valid bundle dropped after it, and starts again on the same state
directory (issue #27). Each attack was proven to stop, block or exhaust the daemon before.

One real daemon process serves the module (simulated controllers on ptys, a Modbus lux sensor on
127.0.0.1); every wait is bounded, so a daemon that blocks fails the test instead of hanging CI.
"""

from __future__ import annotations

import json
import os
import shutil
import socket
import stat
from collections.abc import Callable
from pathlib import Path

import pytest
from daemon_harness import SITE
from test_grassd_run_end_to_end import Daemon, manifest, wait_for

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


def _bundle(d: Daemon, name: str, build: Callable[[Path], None]) -> None:
    """A directory bundle made as an uploader would (hidden name, ``build`` fills it, rename)."""
    tmp = d.state / "inbox" / f".{name}"
    tmp.mkdir(parents=True)
    build(tmp)
    os.rename(tmp, d.state / "inbox" / name)


def _sky(tmp: Path) -> None:
    shutil.copy(SITE, tmp / "sky.exr")


def _manifest_text(tmp: Path, text: str = "", name: str = "manifest.toml") -> None:
    (tmp / name).write_text(manifest(1, lux=1000.0) + text)


def fifo_manifest(tmp: Path) -> None:
    _sky(tmp)
    os.mkfifo(tmp / "manifest.toml")


def dev_zero_manifest(tmp: Path) -> None:
    _sky(tmp)
    os.symlink("/dev/zero", tmp / "manifest.toml")


def nested_toml_100k(tmp: Path) -> None:
    _sky(tmp)
    (tmp / "manifest.toml").write_text("x = " + "[" * 50_000 + "]" * 50_000 + "\n")


def nested_toml_under_cap(tmp: Path) -> None:  # under the size cap: the parser's recursion
    _sky(tmp)
    (tmp / "manifest.toml").write_text("x = " + "[" * 20_000 + "]" * 20_000 + "\n")


def nested_json_under_cap(tmp: Path) -> None:
    _sky(tmp)
    (tmp / "manifest.json").write_text('{"x": ' + "[" * 20_000 + "]" * 20_000 + "}")


def reason_txt_directory(tmp: Path) -> None:
    _sky(tmp)
    (tmp / "reason.txt").mkdir()
    (tmp / "reason.txt" / "inside").write_text("x")
    (tmp / "manifest.toml").write_text("this is not TOML [[[\n")


def huge_manifest_missing_file(tmp: Path) -> None:
    (tmp / "manifest.toml").write_text(manifest(1, lux=1000.0) + "# " + "x" * 3_000_000 + "\n")


def hdri_links_to_huge_file(tmp: Path) -> None:
    huge = tmp.parent.parent / "huge.bin"
    with open(huge, "wb") as fh:  # sparse: 4 GiB that would take the hash minutes
        fh.truncate(4 << 30)
    os.symlink(huge, tmp / "sky.exr")
    _manifest_text(tmp)


def hdri_is_dev_zero_link(tmp: Path) -> None:
    os.symlink("/dev/zero", tmp / "sky.exr")
    _manifest_text(tmp)


def hdri_is_fifo(tmp: Path) -> None:
    os.mkfifo(tmp / "sky.exr")
    _manifest_text(tmp)


def hdri_is_device_node(tmp: Path) -> None:
    if os.geteuid() != 0:
        pytest.skip("mknod of a character device needs root")
    os.mknod(tmp / "sky.exr", 0o600 | stat.S_IFCHR, os.makedev(1, 5))  # /dev/zero's numbers
    _manifest_text(tmp)


def hdri_is_socket(tmp: Path) -> None:
    s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    s.bind(str(tmp / "sky.exr"))
    s.close()
    _manifest_text(tmp)


def hdri_is_hard_link(tmp: Path) -> None:
    other = tmp.parent.parent / "someone-elses.exr"
    shutil.copy(SITE, other)
    os.link(other, tmp / "sky.exr")
    _manifest_text(tmp)


def hdri_is_directory(tmp: Path) -> None:
    (tmp / "sky.exr").mkdir()
    _manifest_text(tmp)


def stray_fifo_in_bundle(tmp: Path) -> None:
    _sky(tmp)
    os.mkfifo(tmp / "notes.txt")
    _manifest_text(tmp)


def too_many_entries(tmp: Path) -> None:
    _sky(tmp)
    for k in range(200):
        (tmp / f"extra{k}.txt").write_text("x")
    _manifest_text(tmp)


def not_utf8(tmp: Path) -> None:
    _sky(tmp)
    (tmp / "manifest.toml").write_bytes(b'timestamp = 2026-06-21T08:00:00+09:00\n'
                                        b'hdri = "\xff\xfe"\n')


#: attack -> a word the reason must hold
ATTACKS = {
    "fifo-manifest": (fifo_manifest, "FIFO"),
    "dev-zero-manifest": (dev_zero_manifest, "symbolic link"),
    "nested-toml-100k": (nested_toml_100k, "over the cap"),
    "nested-toml": (nested_toml_under_cap, "deep"),
    "nested-json": (nested_json_under_cap, "deep"),
    "reason-txt-dir": (reason_txt_directory, "not valid TOML"),
    "huge-manifest-missing-file": (huge_manifest_missing_file, "over the cap"),
    "hdri-link-to-huge-file": (hdri_links_to_huge_file, "symbolic link"),
    "hdri-dev-zero": (hdri_is_dev_zero_link, "symbolic link"),
    "hdri-fifo": (hdri_is_fifo, "FIFO"),
    "hdri-device": (hdri_is_device_node, "character device"),
    "hdri-socket": (hdri_is_socket, "socket"),
    "hdri-hard-link": (hdri_is_hard_link, "hard link"),
    "hdri-directory": (hdri_is_directory, "directory"),
    "stray-fifo": (stray_fifo_in_bundle, "FIFO"),
    "too-many-entries": (too_many_entries, "more than"),
    "not-utf8": (not_utf8, "not valid TOML"),
}


@pytest.fixture(scope="module")
def daemon(tmp_path_factory):
    d = Daemon(tmp_path_factory.mktemp("hostile"))
    d.start()
    yield d
    d.close()


@pytest.mark.parametrize("attack", sorted(ATTACKS))
def test_hostile_bundle_rejected_and_daemon_goes_on(daemon, attack):
    build, word = ATTACKS[attack]
    _bundle(daemon, attack, build)
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
