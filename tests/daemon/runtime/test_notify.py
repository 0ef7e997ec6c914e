"""sd_notify over a real AF_UNIX datagram socket standing in for systemd."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import threading
import time
from types import SimpleNamespace

import pytest

from grassd.daemon.core.runtime import notify
from grassd.daemon.core.runtime.notify import Notifier


def _listener(path_or_abstract):
    s = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    s.bind(path_or_abstract)
    s.settimeout(5)
    return s


def test_messages_reach_a_filesystem_socket(tmp_path):
    path = str(tmp_path / "notify")
    srv = _listener(path)
    n = Notifier(env={"NOTIFY_SOCKET": path})
    assert n.ready(status="watching /inbox")
    msg = srv.recv(4096).decode().split("\n")
    assert msg[0] == "READY=1" and msg[1] == "STATUS=watching /inbox"
    assert msg[2] == f"MAINPID={os.getpid()}"
    assert n.status("calibrating") and srv.recv(4096) == b"STATUS=calibrating"
    assert n.watchdog(force=True) and srv.recv(4096) == b"WATCHDOG=1"
    assert n.reloading() and srv.recv(4096) == b"RELOADING=1"
    assert n.stopping() and srv.recv(4096) == b"STOPPING=1"
    assert n.status("two\nlines") and srv.recv(4096) == b"STATUS=two\\nlines"  # never raises
    n.close()
    srv.close()


def test_abstract_namespace_socket():
    name = f"grassd-test-{os.getpid()}-{time.monotonic_ns()}"
    srv = _listener(b"\0" + name.encode())
    n = Notifier(env={"NOTIFY_SOCKET": "@" + name})
    assert n.send(STATUS="abstract ok")
    assert srv.recv(4096) == b"STATUS=abstract ok"
    srv.close()


def test_watchdog_interval_is_half_of_watchdog_usec(tmp_path, monkeypatch):
    """Pings go out at most every WATCHDOG_USEC / 2. Timed on a clock the test moves (the
    notifier's ``time.monotonic``), so "too early" and "due" do not depend on how fast this
    machine runs the test."""
    now = [1000.0]
    monkeypatch.setattr(notify, "time", SimpleNamespace(monotonic=lambda: now[0]))
    path = str(tmp_path / "n")
    srv = _listener(path)
    srv.setblocking(False)
    n = Notifier(env={"NOTIFY_SOCKET": path, "WATCHDOG_USEC": "400000"})
    assert n.watchdog_interval_s == pytest.approx(0.2)
    assert n.watchdog()            # first ping goes out
    now[0] += 0.19
    assert not n.watchdog()        # too early
    now[0] += 0.02                 # 0.21 s after the first ping
    assert n.watchdog()
    assert not n.watchdog()        # and the interval starts again
    assert [srv.recv(100), srv.recv(100)] == [b"WATCHDOG=1", b"WATCHDOG=1"]
    other_pid = Notifier(env={"NOTIFY_SOCKET": path, "WATCHDOG_USEC": "400000",
                              "WATCHDOG_PID": "1"})
    assert other_pid.watchdog_interval_s is None  # the watchdog is meant for another process


def test_no_socket_is_a_noop_and_missing_socket_is_not_fatal(tmp_path):
    assert Notifier(env={}).ready() is False
    assert Notifier(env={"NOTIFY_SOCKET": str(tmp_path / "gone")}).ready() is False


def test_child_process_notifies_parent(tmp_path):
    """A separate process (as systemd would run it) reaches our socket through the env var."""
    path = str(tmp_path / "notify")
    srv = _listener(path)
    code = "from grassd.daemon.core.runtime.notify import Notifier; Notifier().ready('up')"
    subprocess.run([sys.executable, "-c", code], env={**os.environ, "NOTIFY_SOCKET": path},
                   check=True)
    assert srv.recv(4096).startswith(b"READY=1\nSTATUS=up\nMAINPID=")


def test_full_receiver_never_blocks(tmp_path):
    """Nobody reads the socket: sends fail (False) once its queue is full instead of stalling
    the daemon. A send that blocked would wait for ever (nobody reads), so the sends run in a
    thread and must finish; the deadline only bounds the test, it measures nothing."""
    path = str(tmp_path / "n")
    srv = _listener(path)
    n = Notifier(env={"NOTIFY_SOCKET": path})
    results: list[bool] = []
    sender = threading.Thread(
        target=lambda: results.extend(n.status("x" * 200) for _ in range(5000)), daemon=True)
    sender.start()
    sender.join(60)
    assert not sender.is_alive(), "a send blocked on a receiver that reads nothing"
    assert len(results) == 5000 and results[0] is True and results[-1] is False
    srv.close()


def test_a_hostile_status_is_one_assignment(tmp_path, caplog):
    """A status holding a bundle's name (chosen by whoever writes the inbox) never raises and
    cannot forge another assignment: a newline, NUL, ANSI escape or undecodable byte is sent
    escaped, a very long name is cut below systemd's 4096-byte limit."""
    path = str(tmp_path / "notify")
    srv = _listener(path)
    n = Notifier(env={"NOTIFY_SOCKET": path})
    name = "b1\nREADY=1\nMAINPID=1\r\x00\x1b[31m\udcff" + "\u00e9" * 3000
    assert n.status(f"processing bundle {name}")
    msg = srv.recv(65536)
    assert len(msg) < 4096 and b"\n" not in msg and b"\x00" not in msg and b"\x1b" not in msg
    assert msg.startswith(b"STATUS=processing bundle b1\\nREADY=1\\nMAINPID=1\\r\\x00\\x1b[31m"
                          b"\\xff\xc3\xa9")
    assert msg.endswith(b" more characters)")
    assert n.ready(status="x\ny") and srv.recv(4096).split(b"\n")[:2] == [b"READY=1",
                                                                         b"STATUS=x\\ny"]
    assert not caplog.records  # nothing failed
    n.close()
    srv.close()


def test_a_failing_socket_is_logged_once_and_never_raises(tmp_path, caplog):
    """A socket name that cannot be used (NUL in it, a directory, nobody listening): every
    call returns False; the first failure is a warning, later ones are debug lines."""
    caplog.set_level("DEBUG", logger="grassd.daemon.core.runtime.notify")
    for bad in (f"{tmp_path}/a\0b", str(tmp_path), str(tmp_path / "gone"), "@\udcff"):
        caplog.clear()
        n = Notifier(env={"NOTIFY_SOCKET": bad})
        assert [n.ready("up"), n.status("x"), n.stopping("bye")] == [False] * 3
        assert [r.levelname for r in caplog.records] == ["WARNING", "DEBUG", "DEBUG"], bad
        n.close()
