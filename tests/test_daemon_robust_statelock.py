"""One grassd process per state directory: a running daemon (a real `grassd run` subprocess)
makes a one-shot `grassd calibrate --now` that cannot reach its socket, and a second daemon,
fail at once with one line naming its PID (exit 2); once it stops, the one-shot works."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from robust_util import SITE, write_config

from grassd.daemon.config import load_config, load_default_config
from grassd.daemon.control import request
from grassd.daemon.errors import ControlError, StateDirLocked
from grassd.daemon.service import Service
from grassd.daemon.sim_hardware import SimulatedHardware

GRASSD = str(Path(sys.executable).parent / "grassd")


@pytest.fixture
def hw(tmp_path):
    sim = SimulatedHardware(load_default_config(), tmp_path / "hw", lux=2500.0)
    cfg = sim.start()
    yield sim, cfg
    sim.stop()


def wait_ping(sock: Path, proc: subprocess.Popen, timeout: float = 60) -> dict:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        assert proc.poll() is None, "daemon exited during start"
        try:
            return request(sock, {"cmd": "ping"}, timeout_s=2)
        except ControlError:
            time.sleep(0.1)
    raise AssertionError("daemon did not answer ping")


def test_daemon_excludes_one_shot_and_second_daemon(tmp_path, hw):
    _, cfg = hw
    state = tmp_path / "state"
    conf = write_config(tmp_path / "g.toml", state, cfg, lux="manifest")
    # the same state directory, but a socket nobody listens on: what a one-shot racing a
    # starting daemon (socket not yet bound) sees
    other = tmp_path / "other.toml"
    other.write_text(f'control_socket = "{tmp_path / "none.sock"}"\n' + conf.read_text())
    log = open(tmp_path / "daemon.log", "wb")
    daemon = subprocess.Popen([GRASSD, "run", "--config", str(conf), "--tick", "0.2"],
                              stdout=log, stderr=subprocess.STDOUT)
    try:
        pid = wait_ping(state / "control.sock", daemon)["pid"]
        assert pid == daemon.pid
        one = subprocess.run([GRASSD, "calibrate", "--now", "--config", str(other)],
                             capture_output=True, text=True, timeout=120)
        assert one.returncode == 2, one.stderr
        lines = one.stderr.strip().splitlines()
        assert len(lines) == 1 and f"PID {daemon.pid}" in lines[0] and str(state) in lines[0]
        assert "grassd run" in lines[0]
        two = subprocess.run([GRASSD, "run", "--config", str(other)], capture_output=True,
                             text=True, timeout=120)
        assert two.returncode == 2 and f"PID {daemon.pid}" in two.stderr
        assert len(two.stderr.strip().splitlines()) == 1, two.stderr
        assert not (tmp_path / "none.sock").exists()
        assert request(state / "control.sock", {"cmd": "ping"})["pid"] == daemon.pid  # unharmed
    finally:
        daemon.send_signal(signal.SIGTERM)
        assert daemon.wait(60) == 0
    (state / "inbox" / "b").mkdir()  # the daemon is gone: a one-shot may run now
    (state / "inbox" / "b" / "sky.exr").write_bytes(
        SITE.read_bytes())
    (state / "inbox" / "b" / "manifest.toml").write_text(
        'timestamp = 2026-03-01T12:00:00+01:00\nhdri = "sky.exr"\nambient_lux = 800.0\n')
    ok = subprocess.run([GRASSD, "calibrate", "--now", "--config", str(other)],
                        capture_output=True, text=True, timeout=300)
    assert ok.returncode == 0, ok.stderr


def test_in_process_second_service_is_refused_and_lock_released(tmp_path, hw):
    _, cfg = hw
    conf = write_config(tmp_path / "g.toml", tmp_path / "state", cfg)
    svc = Service(load_config(conf))
    with pytest.raises(StateDirLocked, match=rf"PID {os.getpid()}\)"):
        Service(load_config(conf))
    svc.shutdown()
    Service(load_config(conf)).shutdown()  # released at shutdown
