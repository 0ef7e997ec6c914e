"""The daemon's UNIX control socket: one JSON object per line, one request per connection.

Requests (``{"cmd": ...}``) and answers::

    {"cmd": "ping"}                               -> {"ok": true, "pid": 1234, "version": "..."}
    {"cmd": "status"}                             -> {"ok": true, "status": {...}}
    {"cmd": "calibrate", "force": false, "wait": true}
                                                  -> {"ok": true, "run": {...}} when it finished
                                                     {"ok": true, "queued": 3} without wait
    {"cmd": "reload"}                             -> {"ok": true}  (same as SIGHUP)
    {"cmd": "bundles_retry", "bundle": "NAME"}    -> {"ok": true, "retry": {...}}  (a
                                                     quarantined bundle back into the inbox)

Failures answer ``{"ok": false, "error": "..."}``. The socket lives in the RuntimeDirectory
(``/run/grassd/control.sock``), mode 0660, so members of group grassd may talk to the daemon.

At most ``max_clients`` (8) connections are served at once, each by its own thread; one more
is answered ``{"ok": false, "busy": true, "error": "busy: ..."}`` at once and closed, without a
thread, so a flood of clients cannot exhaust threads or memory (:func:`request` raises
:class:`~grassd.daemon.errors.DaemonBusy` for it). The daemon bounds its queue of calibration
requests the same way.
"""

from __future__ import annotations

import contextlib
import errno
import json
import logging
import os
import socket
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any

from grassd.daemon.errors import ControlError, DaemonBusy, DaemonNotRunning

log = logging.getLogger(__name__)

MAX_REQUEST_BYTES = 64 * 1024
#: Connections served at once; more are answered "busy" straight away.
MAX_CLIENTS = 8
Handler = Callable[[dict[str, Any]], dict[str, Any]]


class ControlServer:
    """Serves ``handler(request) -> answer`` on the UNIX stream socket ``path``: one thread per
    connection, at most ``max_clients`` at once (more are answered "busy")."""

    def __init__(self, path: str | os.PathLike[str], handler: Handler, mode: int = 0o660,
                 max_clients: int = MAX_CLIENTS) -> None:
        self.path = Path(path)
        self.handler = handler
        self.mode = mode
        self.max_clients = max_clients
        self._slots = threading.BoundedSemaphore(max_clients)
        #: connections turned away as busy (for tests and status)
        self.refused = 0
        self._sock: socket.socket | None = None
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()

    def start(self) -> ControlServer:
        """Bind (replacing a stale socket file, refusing a live one) and start accepting."""
        self.path.parent.mkdir(parents=True, exist_ok=True)
        if self.path.exists() or self.path.is_symlink():
            if _alive(self.path):
                raise ControlError(f"another grassd is already listening on {self.path}; stop "
                                   "it first (or use another control_socket)")
            self.path.unlink()
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM | socket.SOCK_CLOEXEC)
        old = os.umask(0o777 & ~self.mode)
        try:
            sock.bind(str(self.path))
        except OSError as exc:
            sock.close()
            raise ControlError(f"cannot create control socket {self.path}: {exc.strerror}") \
                from None
        finally:
            os.umask(old)
        os.chmod(self.path, self.mode)
        sock.listen(16)
        sock.settimeout(0.2)
        self._sock = sock
        self._thread = threading.Thread(target=self._serve, name="control-socket", daemon=True)
        self._thread.start()
        return self

    def _serve(self) -> None:
        assert self._sock is not None
        while not self._stop.is_set():
            try:
                conn, _ = self._sock.accept()
            except TimeoutError:
                continue
            except OSError:
                if self._stop.is_set():
                    return
                continue
            if not self._slots.acquire(blocking=False):
                self._busy(conn)
                continue
            try:
                threading.Thread(target=self._handle, args=(conn,), name="control-conn",
                                 daemon=True).start()
            except RuntimeError:  # cannot start a thread: treat as busy
                self._slots.release()
                self._busy(conn)

    def _busy(self, conn: socket.socket) -> None:
        """Answer "busy" without reading the request, in the accepting thread (never blocks
        long: the answer fits the socket buffer, and a 0.5 s timeout guards it)."""
        self.refused += 1
        with conn:
            conn.settimeout(0.5)
            _send(conn, {"ok": False, "busy": True,
                         "error": f"busy: {self.max_clients} clients are being served; try again "
                                  "in a moment"})
            with contextlib.suppress(OSError):  # drop what it sent already (else: ECONNRESET)
                conn.setblocking(False)
                conn.recv(MAX_REQUEST_BYTES)

    def _handle(self, conn: socket.socket) -> None:
        try:
            self._serve_one(conn)
        finally:
            self._slots.release()

    def _serve_one(self, conn: socket.socket) -> None:
        with conn:
            conn.settimeout(10)
            try:
                req = _read_line(conn)
            except (OSError, ValueError) as exc:
                _send(conn, {"ok": False, "error": f"bad request: {exc}"})
                return
            try:
                if not isinstance(req, dict) or not isinstance(req.get("cmd"), str):
                    raise ValueError('request must be a JSON object with a "cmd" string')
                answer = self.handler(req)
            except Exception as exc:  # reported to the client, daemon lives on
                log.warning("control request %r failed: %s", req, exc)
                answer = {"ok": False, "error": str(exc)}
            conn.settimeout(None)
            _send(conn, answer)

    def stop(self) -> None:
        """Stop accepting and remove the socket file."""
        self._stop.set()
        if self._sock is not None:
            self._sock.close()
            self._sock = None
        if self._thread is not None:
            self._thread.join(2)
        with contextlib.suppress(FileNotFoundError):
            self.path.unlink()


def _send(conn: socket.socket, obj: dict[str, Any]) -> None:
    with contextlib.suppress(OSError):
        conn.sendall(json.dumps(obj, default=str).encode() + b"\n")


def _read_line(conn: socket.socket) -> Any:
    buf = b""
    while b"\n" not in buf:
        chunk = conn.recv(4096)
        if not chunk:
            break
        buf += chunk
        if len(buf) > MAX_REQUEST_BYTES:
            raise ValueError("request too long")
    line = buf.split(b"\n", 1)[0]
    if not line.strip():
        raise ValueError("empty request")
    return json.loads(line)


def _alive(path: Path) -> bool:
    s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    s.settimeout(1)
    try:
        s.connect(str(path))
    except OSError:
        return False
    finally:
        s.close()
    return True


def request(path: str | os.PathLike[str], req: dict[str, Any],
            timeout_s: float | None = 30.0) -> dict[str, Any]:
    """Send one request to the daemon at ``path`` and return its answer.

    Raises :class:`DaemonNotRunning` when nothing listens there, :class:`ControlError` when the
    daemon answers ``ok: false`` or the connection breaks.
    """
    s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    s.settimeout(timeout_s)
    try:
        try:
            s.connect(str(path))
        except (FileNotFoundError, ConnectionRefusedError):
            raise DaemonNotRunning(f"no grassd daemon is listening on {path}") from None
        except OSError as exc:
            if exc.errno in (errno.ENOENT, errno.ECONNREFUSED, errno.ENOTSOCK):
                raise DaemonNotRunning(f"no grassd daemon is listening on {path}") from None
            raise ControlError(f"cannot reach the daemon on {path}: {exc.strerror}") from None
        with contextlib.suppress(OSError):  # a busy daemon answers and closes before reading
            s.sendall(json.dumps(req).encode() + b"\n")
        try:
            answer = _read_line(s)
        except TimeoutError:
            raise ControlError(f"the daemon did not answer within {timeout_s:g} s") from None
        except (OSError, ValueError) as exc:
            raise ControlError(f"bad answer from the daemon: {exc}") from None
    finally:
        s.close()
    if not isinstance(answer, dict):
        raise ControlError(f"bad answer from the daemon: {answer!r}")
    if not answer.get("ok", False):
        if answer.get("busy"):
            raise DaemonBusy(f"daemon: {answer.get('error', 'busy')}")
        raise ControlError(f"daemon: {answer.get('error', 'request failed')}")
    return answer
