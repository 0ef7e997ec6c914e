"""The UNIX control socket: real sockets, concurrent clients, stale and live socket files."""

from __future__ import annotations

import json
import socket
import stat
import threading

import pytest

from grassd.daemon.core.errors import ControlError, DaemonNotRunning
from grassd.daemon.core.runtime.control import ControlServer, request

#: the "together" requests wait here until 5 of them run at once (or fail after 10 s)
together = threading.Barrier(5, timeout=10)


def handler(req):
    if req["cmd"] == "echo":
        return {"ok": True, "echo": req.get("x")}
    if req["cmd"] == "together":
        together.wait()  # BrokenBarrierError if they were served one after the other
        return {"ok": True}
    if req["cmd"] == "boom":
        raise RuntimeError("handler exploded")
    return {"ok": False, "error": f"unknown command {req['cmd']!r}"}


@pytest.fixture
def server(tmp_path):
    srv = ControlServer(tmp_path / "run" / "control.sock", handler).start()
    yield srv
    srv.stop()


def test_roundtrip_and_permissions(server):
    assert request(server.path, {"cmd": "echo", "x": [1, 2]}) == {"ok": True, "echo": [1, 2]}
    assert stat.S_IMODE(server.path.stat().st_mode) == 0o660


def test_errors_are_control_errors_and_server_survives(server):
    with pytest.raises(ControlError, match="handler exploded"):
        request(server.path, {"cmd": "boom"})
    with pytest.raises(ControlError, match="unknown command"):
        request(server.path, {"cmd": "nope"})
    s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    s.connect(str(server.path))
    s.sendall(b"this is not json\n")
    answer = json.loads(s.makefile().readline())
    s.close()
    assert answer["ok"] is False and "bad request" in answer["error"]
    assert request(server.path, {"cmd": "echo", "x": 1})["echo"] == 1


def test_concurrent_clients_are_served_in_parallel(server):
    """Five requests that each wait for the other four: they can only all succeed when they
    are handled at the same time (an event, not a measured duration)."""
    together.reset()
    results = []

    def call():
        results.append(request(server.path, {"cmd": "together"}, timeout_s=20))

    threads = [threading.Thread(target=call) for _ in range(5)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(20)
    assert len(results) == 5 and all(r["ok"] for r in results)


def test_no_daemon_is_daemon_not_running(tmp_path):
    with pytest.raises(DaemonNotRunning):
        request(tmp_path / "none.sock", {"cmd": "ping"})
    stale = tmp_path / "stale.sock"
    s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    s.bind(str(stale))
    s.close()  # a socket file nobody listens on (daemon was killed)
    with pytest.raises(DaemonNotRunning):
        request(stale, {"cmd": "ping"})
    srv = ControlServer(stale, handler).start()  # stale file is replaced
    try:
        assert request(stale, {"cmd": "echo", "x": 3})["echo"] == 3
        with pytest.raises(ControlError, match="already listening"):
            ControlServer(stale, handler).start()  # a live one is not
    finally:
        srv.stop()
    assert not stale.exists()
