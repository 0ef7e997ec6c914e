"""Hostile clients on the control socket, each against a real running
:class:`ControlServer` on a real UNIX socket: slow-loris clients that trickle a byte now and
then, nested or oversized JSON, handlers that raise anything, clients that never read their
answer, and peers that may not change the daemon's state (checked with ``SO_PEERCRED``).

Every wait is bounded (socket timeouts, bounded polls of the server's counters), and the
assertions wait on events (a connection cut, a slot given back), not on the wall clock.
"""

from __future__ import annotations

import json
import logging
import os
import select
import shutil
import socket
import statistics
import tempfile
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
from daemon_harness import wait_for, write_config

from grassd.daemon.core.config.settings import load_config
from grassd.daemon.core.errors import ControlError, DaemonBusy
from grassd.daemon.core.runtime.control import (
    GROUP_ENV,
    MAX_CLIENTS,
    MAX_REQUEST_BYTES,
    ControlServer,
    request,
)
from grassd.daemon.core.runtime.service import Service

NOBODY = 65534
BOUND_S = 20.0  # the most any single wait of these tests may take


def wait_until(cond: Callable[[], Any], what: str, timeout: float = BOUND_S) -> Any:
    """Poll ``cond`` until it is true (bounded)."""
    return wait_for(cond, timeout, what, poll=0.01)


def read_answer(s: socket.socket, timeout: float = BOUND_S) -> dict:
    """The answer line on ``s`` (bounded by ``timeout`` in all)."""
    deadline = time.monotonic() + timeout
    buf = b""
    while b"\n" not in buf:
        s.settimeout(max(deadline - time.monotonic(), 0.001))
        try:
            chunk = s.recv(65536)
        except ConnectionResetError:
            break
        if not chunk:
            break
        buf += chunk
    assert buf, "no answer"
    return json.loads(buf.split(b"\n", 1)[0])


def raw(path: Path, data: bytes) -> dict:
    """Send ``data`` as is and return the answer."""
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as s:
        s.settimeout(BOUND_S)
        s.connect(str(path))
        try:
            s.sendall(data)
        except (BrokenPipeError, ConnectionResetError):
            pass  # the server may answer and close before taking all of it
        return read_answer(s)


class SlowLoris:
    """``n`` clients that each send the start of a request and then one byte every
    ``every_s`` seconds, never the newline: a per-read timeout would never fire."""

    def __init__(self, path: Path, n: int, every_s: float = 0.05) -> None:
        self.socks = []
        for _ in range(n):
            s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
            s.settimeout(BOUND_S)
            s.connect(str(path))
            s.sendall(b'{"cmd": "status", "pad": "')
            self.socks.append(s)
        self.stop = threading.Event()
        self.every_s = every_s
        self.thread = threading.Thread(target=self._trickle, daemon=True)
        self.thread.start()

    def _trickle(self) -> None:
        while not self.stop.wait(self.every_s):
            for s in self.socks:
                try:
                    s.send(b" ")
                except OSError:
                    pass  # cut by the server

    def none_answered(self) -> bool:
        """No slow client has been answered or closed yet."""
        readable, _, _ = select.select(self.socks, [], [], 0)
        return not readable

    def close(self) -> None:
        self.stop.set()
        self.thread.join(5)
        for s in self.socks:
            s.close()


@pytest.fixture
def uncaught(monkeypatch) -> list:
    """Exceptions that escape any thread (a dead handler thread would land here)."""
    seen: list = []
    monkeypatch.setattr(threading, "excepthook", lambda args: seen.append(args.exc_value))
    return seen


def status_handler(req: dict) -> dict:
    if req["cmd"] == "status":
        return {"ok": True, "status": {"activity": "idle"}}
    if req["cmd"] == "ping":
        return {"ok": True, "pid": os.getpid()}
    return {"ok": True, "did": req["cmd"]}


@pytest.fixture
def server(tmp_path) -> Iterator[ControlServer]:
    srv = ControlServer(tmp_path / "run" / "control.sock", status_handler,
                        request_deadline_s=60).start()
    yield srv
    srv.stop()


# ---------------------------------------------------------------------- slow clients
def test_status_is_answered_while_slow_loris_clients_hold_connections(server, uncaught):
    n = 2 * MAX_CLIENTS  # more than every handler slot
    loris = SlowLoris(server.path, n)
    try:
        wait_until(lambda: server.pending == n, f"{n} slow clients connected")
        latencies = []
        for _ in range(20):
            t0 = time.monotonic()
            assert request(server.path, {"cmd": "status"}, timeout_s=BOUND_S)["ok"]
            latencies.append(time.monotonic() - t0)
        # answered while every slow client was still connected and unanswered (their 60 s
        # request deadline had not passed): they hold no slot that status needs
        assert server.pending == n and loris.none_answered()
        assert server.refused == 0 and server.timed_out == 0
        print(f"status with {n} slow-loris clients connected: median "
              f"{statistics.median(latencies) * 1e3:.2f} ms, max {max(latencies) * 1e3:.2f} ms")
    finally:
        loris.close()
    assert not uncaught


def test_slow_loris_clients_are_cut_at_the_total_deadline(tmp_path, uncaught):
    srv = ControlServer(tmp_path / "c.sock", status_handler, request_deadline_s=0.5).start()
    n = MAX_CLIENTS + 2
    try:
        # each sends a byte every 50 ms, ten times within the deadline: only a deadline for
        # the whole request (not one per read) can cut them
        loris = SlowLoris(srv.path, n, every_s=0.05)
        try:
            t0 = time.monotonic()
            answers = [read_answer(s) for s in loris.socks]
            took = time.monotonic() - t0
        finally:
            loris.close()
        for a in answers:
            assert a["ok"] is False
            assert "no complete request line within 0.5 s" in a["error"]
        assert srv.timed_out == n
        wait_until(lambda: srv.pending == 0, "slow clients forgotten")
        assert request(srv.path, {"cmd": "status"}, timeout_s=BOUND_S)["ok"]
        print(f"{n} slow-loris clients cut {took:.2f} s after connecting (deadline 0.5 s)")
    finally:
        srv.stop()
    assert not uncaught


@pytest.mark.parametrize("evict", [True, False], ids=["oldest-cut", "all-fresh-busy"])
def test_silent_connections_of_one_user_are_capped(tmp_path, evict):
    """Four silent connections fill the user's share: a fifth one (status) cuts the oldest of
    them, or, while they are all younger than ``evict_after_s``, is told busy."""
    srv = ControlServer(tmp_path / "c.sock", status_handler, request_deadline_s=60,
                        max_pending_per_uid=4, evict_after_s=0 if evict else 60).start()
    socks = []
    try:
        for _ in range(4):
            s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
            s.connect(str(srv.path))
            socks.append(s)
        wait_until(lambda: srv.pending == 4, "4 silent clients")
        if evict:
            assert request(srv.path, {"cmd": "status"}, timeout_s=BOUND_S)["ok"]
            assert "cut to make room" in read_answer(socks[0])["error"]
            assert srv.evicted == 1 and srv.pending == 3
            return
        with pytest.raises(DaemonBusy, match="still sending their request"):
            request(srv.path, {"cmd": "status"}, timeout_s=BOUND_S)
        for s in socks:  # the slots come back as soon as they go
            s.close()
        wait_until(lambda: srv.pending == 0, "silent clients gone")
        assert request(srv.path, {"cmd": "status"}, timeout_s=BOUND_S)["ok"]
    finally:
        for s in socks:
            s.close()
        srv.stop()


def test_a_flood_beyond_every_share_still_lets_status_in(tmp_path, uncaught):
    """More slow clients than the server reads at once (and than one user's share): each new
    connection cuts the oldest slow one, so a status request is answered all the same."""
    srv = ControlServer(tmp_path / "c.sock", status_handler, request_deadline_s=60,
                        max_pending=16, max_pending_per_uid=8, evict_after_s=0).start()
    loris = SlowLoris(srv.path, 40)
    try:
        wait_until(lambda: srv.evicted == 32, "32 oldest slow clients cut")
        assert request(srv.path, {"cmd": "status"}, timeout_s=BOUND_S)["ok"]
        assert srv.pending == 7 and srv.refused == 0
    finally:
        loris.close()
        srv.stop()
    assert not uncaught


# ---------------------------------------------------------------------- hostile requests
@pytest.mark.parametrize(("data", "error"), [
    (b"[" * 100_000, f"longer than {MAX_REQUEST_BYTES} bytes"),
    (b"[" * (MAX_REQUEST_BYTES - 10) + b"\n", "nested too deeply"),
    (b'{"cmd": "status", "x": ' + b"[" * 5000 + b"]" * 5000 + b"}\n", "nested too deeply"),
    (b'{"cmd": "status", "x": ' + b"{\"a\": " * 2000 + b"\n", "nested too deeply"),
    (b'{"cmd": "status", "x": ' + b"1" * 10_000 + b"}\n", "bad request"),
    (b'{"cmd": "st\xff\xfe"}\n', "bad request"),
    (b"\n", "empty request"),
    (b"[1, 2]\n", 'JSON object with a "cmd" string'),
    (b'{"cmd": 7}\n', 'JSON object with a "cmd" string'),
    (b"", "empty request"),  # connect, then close the sending side at once
], ids=["100kB-nested", "nested-array", "nested-in-object", "nested-objects", "huge-int",
        "not-utf8", "empty-line", "not-an-object", "cmd-not-a-string", "eof"])
def test_hostile_request_is_answered_and_server_keeps_serving(server, uncaught, data, error):
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as s:
        s.settimeout(BOUND_S)
        s.connect(str(server.path))
        try:
            s.sendall(data)
            s.shutdown(socket.SHUT_WR)
        except (BrokenPipeError, ConnectionResetError):
            pass
        answer = read_answer(s)
    assert answer["ok"] is False and error in answer["error"], answer
    assert request(server.path, {"cmd": "status"}, timeout_s=BOUND_S)["ok"]
    wait_until(lambda: server.active == 0 and server.pending == 0, "connections done")
    assert not uncaught


@pytest.mark.parametrize(("exc", "said"), [
    (RecursionError("maximum recursion depth exceeded"), "nested too deeply"),
    (MemoryError(), "out of memory"),
    (ValueError("bad value\nforged line"), "bad value forged line"),
    (KeyError("bundle"), "'bundle'"),
    (OSError(28, "No space left on device"), "No space left on device"),
])
def test_every_handler_exception_is_answered(tmp_path, uncaught, exc, said):
    def handler(req):
        raise exc

    srv = ControlServer(tmp_path / "c.sock", handler).start()
    try:
        for _ in range(2 * MAX_CLIENTS):  # a slot that was not given back would show here
            with pytest.raises(ControlError, match=said) as err:
                request(srv.path, {"cmd": "status"}, timeout_s=BOUND_S)
            assert "\n" not in str(err.value)
        wait_until(lambda: srv.active == 0, "slots given back")
    finally:
        srv.stop()
    assert not uncaught


@pytest.mark.parametrize("answer", [None, "ok", {"ok": True, "loop": None}],
                         ids=["none", "not-a-dict", "circular"])
def test_an_unusable_handler_answer_is_an_error_answer(tmp_path, uncaught, answer):
    if isinstance(answer, dict):
        answer["loop"] = answer  # json.dumps: "Circular reference detected"
    srv = ControlServer(tmp_path / "c.sock", lambda req: answer).start()
    try:
        with pytest.raises(ControlError, match="daemon: "):
            request(srv.path, {"cmd": "status"}, timeout_s=BOUND_S)
        wait_until(lambda: srv.active == 0, "slot given back")
    finally:
        srv.stop()
    assert not uncaught


def test_a_client_that_never_reads_its_answer_loses_its_slot(tmp_path, uncaught):
    big = "x" * (32 << 20)  # far more than the socket buffers hold

    def handler(req):
        return {"ok": True, "blob": big} if req["cmd"] == "big" else {"ok": True}

    srv = ControlServer(tmp_path / "c.sock", handler, max_clients=1,
                        answer_deadline_s=0.5).start()
    try:
        with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as s:
            s.connect(str(srv.path))
            s.sendall(b'{"cmd": "big"}\n')  # and never reads
            wait_until(lambda: srv.active == 1, "the big answer being sent")
            # its only slot is given back at the answer deadline, though the client is still
            # connected (without the deadline sendall would block for ever)
            wait_until(lambda: srv.active == 0, "the slot given back")
            assert request(srv.path, {"cmd": "ping"}, timeout_s=BOUND_S)["ok"]
    finally:
        srv.stop()
    assert not uncaught


# ---------------------------------------------------------------------- who may do what
def test_state_changing_commands_are_refused_to_other_users(tmp_path, caplog):
    calls: list[str] = []

    def handler(req):
        calls.append(req["cmd"])
        return {"ok": True}

    # the daemon's user is someone else, and root is not privileged here either: this test
    # process is just another member of the readers' group
    other = os.geteuid() + 4242
    srv = ControlServer(tmp_path / "c.sock", handler, privileged_uids={other}).start()
    try:
        assert request(srv.path, {"cmd": "status"})["ok"]
        assert request(srv.path, {"cmd": "ping"})["ok"]
        for req in ({"cmd": "calibrate", "force": True, "wait": False}, {"cmd": "reload"},
                    {"cmd": "bundles_retry", "bundle": "b1"}, {"cmd": "shutdown"}):
            with pytest.raises(ControlError, match="permission denied") as err:
                request(srv.path, req)
            assert f"you are uid {os.geteuid()}" in str(err.value)
            assert "ping, status" in str(err.value)
        assert calls == ["status", "ping"]  # the refused ones never reached the handler
        assert srv.denied == 4
        assert "'calibrate' refused for uid" in caplog.text
    finally:
        srv.stop()
    # the default: root and the daemon's own user (here: this process) may
    srv = ControlServer(tmp_path / "d.sock", handler).start()
    try:
        assert request(srv.path, {"cmd": "calibrate"})["ok"]
        assert calls[-1] == "calibrate"
    finally:
        srv.stop()


def _run_as(uid: int, fn: Callable[[], Any], timeout: float = BOUND_S) -> Any:
    """Run ``fn`` in a forked child as user and group ``uid``; return what it returned (JSON)
    or raise what it raised, as a ControlError with the message."""
    r, w = os.pipe()
    pid = os.fork()
    if pid == 0:  # child: no pytest, no logging; only sockets and os
        code = 0
        try:
            os.close(r)
            os.setgroups([])
            os.setgid(uid)
            os.setuid(uid)
            try:
                out = {"value": fn()}
            except Exception as exc:
                out = {"error": f"{type(exc).__name__}: {exc}"}
            os.write(w, json.dumps(out).encode())
        except BaseException:
            code = 1
        finally:
            os._exit(code)
    os.close(w)
    try:
        data = b""
        deadline = time.monotonic() + timeout
        while True:
            left = deadline - time.monotonic()
            assert left > 0, "child did not finish"
            ready, _, _ = select.select([r], [], [], left)
            if ready:
                chunk = os.read(r, 65536)
                if not chunk:
                    break
                data += chunk
    finally:
        os.close(r)
        deadline = time.monotonic() + 5
        while os.waitpid(pid, os.WNOHANG) == (0, 0) and time.monotonic() < deadline:
            time.sleep(0.01)
    out = json.loads(data)
    if "error" in out:
        raise ControlError(out["error"])
    return out["value"]


@pytest.fixture
def shared_dir() -> Iterator[Path]:
    """A directory other users can reach (pytest's tmp_path is private to root)."""
    d = Path(tempfile.mkdtemp(prefix="grassd-ctl-"))
    d.chmod(0o755)
    yield d
    shutil.rmtree(d, ignore_errors=True)


@pytest.mark.skipif(os.geteuid() != 0, reason="needs root to connect as another user")
def test_another_user_reads_status_but_may_not_change_anything(shared_dir, uncaught):
    """The shipped defaults: root and the daemon's user may do everything, a member of the
    readers' group (here: nobody, through a 0666 socket) only read; its uid comes from the
    kernel (SO_PEERCRED). Silent connections of root fill root's share of pending slots; the
    other user's status is still answered."""
    calls: list[str] = []

    def handler(req):
        calls.append(req["cmd"])
        return {"ok": True, "cmd": req["cmd"]}

    sock = shared_dir / "control.sock"
    srv = ControlServer(sock, handler, mode=0o666, request_deadline_s=60,
                        max_pending_per_uid=4).start()
    hogs = []
    try:
        for _ in range(4):
            s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
            s.connect(str(sock))
            hogs.append(s)
        wait_until(lambda: srv.pending == 4, "root's silent clients")
        assert _run_as(NOBODY, lambda: request(sock, {"cmd": "status"}, timeout_s=10))["ok"]
        with pytest.raises(ControlError, match=f"permission denied.*you are uid {NOBODY}"):
            _run_as(NOBODY, lambda: request(sock, {"cmd": "calibrate", "force": True},
                                            timeout_s=10))
        with pytest.raises(ControlError, match="permission denied"):
            _run_as(NOBODY, lambda: request(sock, {"cmd": "bundles_retry", "bundle": "x"},
                                            timeout_s=10))
        # a forged uid in the request changes nothing: the kernel says who connected
        with pytest.raises(ControlError, match="permission denied"):
            _run_as(NOBODY, lambda: request(sock, {"cmd": "reload", "uid": 0}, timeout_s=10))
        for s in hogs:
            s.close()
        hogs.clear()
        assert request(sock, {"cmd": "calibrate"}, timeout_s=10)["ok"]  # root may
        assert calls == ["status", "calibrate"]
    finally:
        for s in hogs:
            s.close()
        srv.stop()
    assert not uncaught


@pytest.mark.skipif(os.geteuid() != 0, reason="needs root to connect as another user")
def test_a_user_without_access_is_told_which_group_to_join(shared_dir):
    sock = shared_dir / "control.sock"
    srv = ControlServer(sock, status_handler, mode=0o660).start()  # root:root 0660
    try:
        with pytest.raises(ControlError, match="no permission to talk to the daemon") as err:
            _run_as(NOBODY, lambda: request(sock, {"cmd": "status"}, timeout_s=10))
        assert "usermod -aG root USER" in str(err.value)
    finally:
        srv.stop()


def test_socket_is_handed_to_the_readers_group(tmp_path, monkeypatch, caplog):
    gid = os.getgroups()[0] if os.getgroups() else os.getgid()
    srv = ControlServer(tmp_path / "a.sock", status_handler, group=gid).start()
    try:
        assert srv.path.stat().st_gid == gid
    finally:
        srv.stop()
    monkeypatch.setenv(GROUP_ENV, str(gid))  # from the unit's environment, as a number
    srv = ControlServer(tmp_path / "n.sock", status_handler).start()
    try:
        assert srv.path.stat().st_gid == gid
    finally:
        srv.stop()
    monkeypatch.setenv(GROUP_ENV, "no-such-group-grassd")
    with caplog.at_level(logging.WARNING):
        srv = ControlServer(tmp_path / "b.sock", status_handler).start()
    try:  # a missing group is said, with the fix; the daemon goes on
        assert "cannot give control socket" in caplog.text and "no such group" in caplog.text
        assert "systemd-sysusers" in caplog.text
        assert request(srv.path, {"cmd": "status"})["ok"]
    finally:
        srv.stop()


# ---------------------------------------------------------------------- the real daemon
def test_the_daemon_handler_under_hostile_clients(tmp_path, hw, uncaught):
    """The same attacks against the daemon's own handler (``Service.handle_request``): slow
    clients, nested JSON, a reader asking for a calibration; status answers throughout and
    nothing is queued."""
    _, cfg = hw
    conf = write_config(tmp_path / "g.toml", tmp_path / "state", cfg)
    svc = Service(load_config(conf))  # its main loop does not run here
    srv = ControlServer(tmp_path / "d.sock", svc.handle_request, request_deadline_s=60,
                        privileged_uids={os.geteuid() + 4242}).start()
    loris = SlowLoris(srv.path, 2 * MAX_CLIENTS)
    try:
        wait_until(lambda: srv.pending == 2 * MAX_CLIENTS, "slow clients connected")
        assert request(srv.path, {"cmd": "status"}, timeout_s=BOUND_S)["status"]
        answer = raw(srv.path, b'{"cmd": "calibrate", "x": ' + b"[" * 5000 + b"\n")
        assert answer["ok"] is False and "nested too deeply" in answer["error"]
        with pytest.raises(ControlError, match="permission denied"):
            request(srv.path, {"cmd": "calibrate", "force": True}, timeout_s=BOUND_S)
        assert svc.requests.qsize() == 0
        assert request(srv.path, {"cmd": "status"}, timeout_s=BOUND_S)["ok"]
        assert loris.none_answered()
    finally:
        loris.close()
        srv.stop()
        svc.shutdown()
    assert not uncaught
