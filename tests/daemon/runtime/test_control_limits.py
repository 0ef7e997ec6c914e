"""The control socket bounds its clients and the daemon its queue of calibration requests: real
UNIX sockets, real threads; excess clients get a clear "busy" answer at once instead of a new
thread each (or an unbounded queue)."""

from __future__ import annotations

import json
import socket
import threading
import time

import pytest
from daemon_harness import write_config

from grassd.daemon.core.config.settings import load_config
from grassd.daemon.core.errors import DaemonBusy
from grassd.daemon.core.runtime.control import MAX_CLIENTS, ControlServer, request
from grassd.daemon.core.runtime.service import Service


def test_excess_clients_are_told_busy_without_threads(tmp_path):
    release = threading.Event()
    entered = []

    def handler(req):
        entered.append(req["cmd"])
        release.wait(20)
        return {"ok": True, "cmd": req["cmd"]}

    srv = ControlServer(tmp_path / "c.sock", handler).start()
    answers: list = []
    try:
        workers = [threading.Thread(target=lambda: answers.append(
            request(srv.path, {"cmd": "hold"}, timeout_s=30))) for _ in range(MAX_CLIENTS)]
        for t in workers:
            t.start()
        deadline = time.monotonic() + 10
        while len(entered) < MAX_CLIENTS and time.monotonic() < deadline:
            time.sleep(0.02)
        assert len(entered) == MAX_CLIENTS
        threads_busy = threading.active_count()
        # a flood of idle connections that never send anything: each is answered at once
        for _ in range(40):
            s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
            s.settimeout(5)
            s.connect(str(srv.path))
            line = s.makefile("rb").readline()
            answer = json.loads(line)
            assert answer["ok"] is False and answer["busy"] is True
            assert f"busy: {MAX_CLIENTS} clients" in answer["error"]
            s.close()
        # answered busy, not left hanging (that would be a ControlError "did not answer")
        with pytest.raises(DaemonBusy, match="busy"):
            request(srv.path, {"cmd": "ping"}, timeout_s=30)
        assert threading.active_count() <= threads_busy  # no thread per refused client
        assert srv.refused == 41
        release.set()
        for t in workers:
            t.join(10)
        assert len(answers) == MAX_CLIENTS and all(a["ok"] for a in answers)
        assert request(srv.path, {"cmd": "ping"})["cmd"] == "ping"  # slots were given back
    finally:
        release.set()
        srv.stop()


def test_calibration_queue_is_bounded(tmp_path, hw):
    _, cfg = hw
    conf = write_config(tmp_path / "g.toml", tmp_path / "state", cfg)
    svc = Service(load_config(conf), max_queued=3)  # its main loop does not run here
    srv = ControlServer(tmp_path / "d.sock", svc.handle_request).start()
    try:
        queued = [request(srv.path, {"cmd": "calibrate"})["queued"] for _ in range(3)]
        assert queued == [1, 2, 3]
        with pytest.raises(DaemonBusy, match="3 calibration requests are already queued"):
            request(srv.path, {"cmd": "calibrate", "wait": True})
        assert svc.requests.qsize() == 3
        assert request(srv.path, {"cmd": "status"})["ok"]  # status still answers
    finally:
        srv.stop()
        svc.shutdown()
