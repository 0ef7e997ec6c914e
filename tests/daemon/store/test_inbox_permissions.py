"""A directory bundle written by another user with umask 022 (mode 0755, not writable by the
daemon) cannot be renamed out of the inbox (moving a directory rewrites its '..'). A real
`grassd run` (as root: with CAP_DAC_OVERRIDE/CAP_FOWNER dropped by setpriv, so permissions
apply to it as to the grassd user; else as ourselves with a 0555 bundle) must say so once,
naming the fix, in its log and status; not crash, not re-hash or journal the bundle every tick;
and pick the bundle up as soon as its mode is fixed."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from daemon_harness import SITE, wait_for, write_config

from grassd.daemon.core.errors import ControlError
from grassd.daemon.core.runtime.control import request
from grassd.daemon.core.store.history import History

GRASSD = str(Path(sys.executable).parent / "grassd")
OTHER_UID = 1000


def daemon_argv(conf: Path) -> list[str]:
    argv = [GRASSD, "run", "--config", str(conf), "--tick", "0.2"]
    if os.geteuid() != 0:
        return argv
    if shutil.which("setpriv") is None:
        pytest.skip("root without setpriv: the daemon would bypass file permissions")
    return ["setpriv", "--bounding-set=-dac_override,-fowner,-dac_read_search", "--", *argv]


def status(sock: Path, proc: subprocess.Popen, timeout: float = 60) -> dict:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        assert proc.poll() is None, "daemon died"
        try:
            return request(sock, {"cmd": "status"}, timeout_s=5)["status"]
        except ControlError:
            time.sleep(0.1)
    raise AssertionError("daemon did not answer")




def test_unmovable_bundle_is_reported_once_and_taken_when_fixed(tmp_path, hw):
    _, cfg = hw
    state = tmp_path / "state"
    conf = write_config(tmp_path / "g.toml", state, cfg, lux="manifest")
    inbox = state / "inbox"
    inbox.mkdir(parents=True)
    os.chmod(inbox, 0o777)  # the uploader may write here
    log = tmp_path / "daemon.log"
    proc = subprocess.Popen(daemon_argv(conf), stdout=open(log, "wb"), stderr=subprocess.STDOUT)
    try:
        sock = state / "control.sock"
        status(sock, proc)
        # the other user's upload: a directory with mode 0755 (umask 022)
        tmp = inbox / ".b1"
        tmp.mkdir()
        shutil.copy(SITE, tmp / "sky.exr")
        (tmp / "manifest.toml").write_text('timestamp = 2026-03-01T12:00:00+01:00\n'
                                           'hdri = "sky.exr"\nambient_lux = 900.0\n')
        if os.geteuid() == 0:
            for p in (tmp, tmp / "sky.exr", tmp / "manifest.toml"):
                os.chown(p, OTHER_UID, OTHER_UID)
            os.chmod(tmp, 0o755)
        else:
            os.chmod(tmp, 0o555)
        tmp.rename(inbox / "b1")

        st = wait_for(lambda: status(sock, proc)["inbox_problems"], 30, "inbox problem")
        [msg] = st
        assert "cannot move bundle b1" in msg and "Permission denied" in msg
        assert "umask 002" in msg and f"chmod 2775 {inbox}" in msg
        time.sleep(2.0)  # ten more ticks: no crash, no retry, no second log line
        st = status(sock, proc)
        assert st["inbox_problems"] == [msg] and st["inbox"]["inbox"] == 1
        assert st["run_counts"] == {"ok": 0, "rejected": 0, "failed": 0, "superseded": 0}
        assert log.read_text().count("cannot move bundle b1") == 1
        with History(state / "state.db") as h:
            assert h.journal() == []

        os.chmod(inbox / "b1", 0o777)  # the fix: the daemon retries at once, not in a minute
        def archived() -> dict | None:  # the run row is finished before the bundle moves
            s = status(sock, proc)
            return s if s["run_counts"]["ok"] == 1 and s["inbox"]["archive"] == 1 else None

        st = wait_for(archived, 60, "the run and the archived bundle")
        assert st["inbox_problems"] == []
    finally:
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(60) == 0
