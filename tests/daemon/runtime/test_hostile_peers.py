"""A running `grassd run` whose camera and control-socket clients are hostile: the
capture station's camera answers every request with a 300 MiB body, 16 clients hold the control
socket open with a byte now and then, and one sends JSON nested past the parser's recursion
limit. The daemon stays up: the capture fails with a typed error that status shows, `status`
is answered, the nested request gets an error, and a valid bundle is still calibrated."""

from __future__ import annotations

import json
import socket
import time

import pytest
from test_grassd_run_end_to_end import Daemon, config_text, manifest, wait_for

from grassd.rigs.hostile_camera import HostileServer

#: seconds for a capture attempt or a calibration on a loaded 2-core CI machine
WAIT_S = 90.0


@pytest.fixture(scope="module")
def hostile_camera():
    with HostileServer() as srv:
        yield srv


@pytest.fixture(scope="module")
def daemon(tmp_path_factory, hostile_camera):
    d = Daemon(tmp_path_factory.mktemp("peers"))
    d.config.write_text(config_text(d.state, d.cfg, extra=f"""[capture]
camera = "{hostile_camera.url}/huge"
interval_s = 3600
retries = 0
"""))
    d.start()
    yield d
    d.close()


def test_a_camera_sending_300_mib_answers_is_cut_and_reported(daemon, hostile_camera):
    d = daemon

    def capture_error():
        cap = d.status().get("capture") or {}
        return cap.get("last_error")

    error = wait_for(capture_error, WAIT_S, "the failed capture in status", d)
    print(f"\n  capture: {error[:200]}")
    assert "cap of" in error and "bytes" in error
    assert hostile_camera.sent < 64 << 20  # the daemon stopped reading: not 300 MiB
    assert d.proc.poll() is None


def test_slow_and_nested_control_clients_leave_status_answered(daemon):
    d = daemon
    sock = d.state / "control.sock"
    slow = []
    try:
        for _ in range(16):
            s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
            s.connect(str(sock))
            s.send(b"{")
            slow.append(s)
        for _ in range(5):
            for s in slow:
                try:
                    s.send(b" ")
                except OSError:
                    pass  # cut at its deadline: what should happen
            t0 = time.monotonic()
            assert d.status()["running"]
            assert time.monotonic() - t0 < 10
        raw = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        raw.settimeout(30)
        raw.connect(str(sock))
        raw.sendall(b"[" * 8000 + b"]" * 8000 + b"\n")
        answer = json.loads(raw.makefile("rb").readline())
        raw.close()
        assert answer["ok"] is False and "bad request" in answer["error"]
    finally:
        for s in slow:
            s.close()
    d.drop("after-peers", manifest(30, lux=3000.0))
    wait_for(lambda: any(p.name.endswith("-after-peers") for p in (d.state / "archive")
                         .iterdir()), WAIT_S, "a valid bundle archived after the attacks", d)
    assert d.status()["run_counts"]["ok"] >= 1
