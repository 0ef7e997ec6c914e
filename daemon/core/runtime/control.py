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
(``/run/grassd/control.sock``), mode 0660; under the shipped systemd unit its group is the
readers' group ``grassd-status`` (``$GRASSD_CONTROL_GROUP``, see ``systemd/grassd.service``).

Who may do what (the peer's credentials come from ``SO_PEERCRED``, not from the request):
anyone who can connect may send the read-only commands (``ping``, ``status``:
:data:`~grassd.daemon.core.runtime.control_commands.READ_ONLY_COMMANDS`); every command that
changes the daemon's state (``calibrate``, ``reload``, ``bundles_retry``) is served only for
root and the daemon's own user, others are answered ``{"ok": false, "denied": true, ...}``.

What a client can hold, and for how long (every client is treated as hostile):

* reading a request costs no thread: one thread reads every connection at once (a selector),
  and each connection has a total deadline (:data:`REQUEST_DEADLINE_S`, not a per-read
  timeout) to deliver its request line of at most :data:`MAX_REQUEST_BYTES`; a client that
  trickles a byte now and then is answered an error and closed at the deadline. At most
  :data:`MAX_PENDING` connections are read at once, :data:`MAX_PENDING_PER_UID` per user;
  when that is full, a new connection makes room by cutting the oldest one of its user (or of
  the user holding the most), so slow clients cannot keep a ``status`` out even when they run
  as the same user;
* a complete request is parsed there (a parse error of any kind, ``RecursionError`` from
  nested arrays and ``MemoryError`` included, is answered, never raised), checked against the
  peer, and served by a thread of its own: at most ``max_clients`` (8) at once; one more is
  answered ``{"ok": false, "busy": true, "error": "busy: ..."}`` at once and closed
  (:func:`request` raises :class:`~grassd.daemon.core.errors.DaemonBusy` for it). The daemon bounds
  its queue of calibration requests below that (4), so clients waiting for runs cannot hold
  every slot;
* every exception of a handler is answered ``ok: false`` and the thread ends normally; the
  answer must be taken within :data:`ANSWER_DEADLINE_S` (one total deadline), else the
  connection is closed and its slot given back.
"""

from __future__ import annotations

import contextlib
import errno
import grp
import json
import logging
import math
import os
import selectors
import socket
import struct
import threading
import time
from collections.abc import Callable, Collection
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeAlias

from grassd.daemon.core.errors import ControlError, DaemonBusy, DaemonNotRunning
from grassd.daemon.core.runtime.control_commands import (
    READ_ONLY_COMMANDS,
    Answer,
    Request,
    command,
)

log = logging.getLogger(__name__)

#: The longest request line the server reads (a request is a command and a bundle name).
MAX_REQUEST_BYTES = 16 * 1024
#: The longest answer :func:`request` reads (a status of a large installation fits).
MAX_ANSWER_BYTES = 64 * 1024 * 1024
#: Connections served at once (a thread each); more are answered "busy" straight away.
MAX_CLIENTS = 8
#: Connections whose request is still being read (no thread each), in all and per user.
MAX_PENDING = 128
MAX_PENDING_PER_UID = 32
#: When those are full, a new connection cuts the one of the same user (or of the user with
#: the most) that has been sending longest, if that one is older than this; else it is busy.
EVICT_AFTER_S = 0.2
#: Seconds a client has to deliver its whole request line, from accept().
REQUEST_DEADLINE_S = 5.0
#: Seconds a client has to take its whole answer, once the handler returned.
ANSWER_DEADLINE_S = 5.0
#: Environment variable naming the group the socket is handed to (the readers' group).
GROUP_ENV = "GRASSD_CONTROL_GROUP"
Handler: TypeAlias = Callable[[Request], Answer]
_PEERCRED = struct.Struct("3i")  # struct ucred: pid, uid, gid


@dataclass(frozen=True)
class Peer:
    """The credentials of a connected client (``SO_PEERCRED``); ``uid`` -1 where the kernel
    did not say (then only read-only commands are served)."""

    pid: int
    uid: int
    gid: int


@dataclass
class _Pending:
    """A connection whose request line is still arriving."""

    conn: socket.socket
    peer: Peer
    deadline: float
    buf: bytearray = field(default_factory=bytearray)


class ControlServer:
    """Serves ``handler(request) -> answer`` on the UNIX stream socket ``path``.

    Requests are read by one selector thread with a total deadline per connection; each
    complete, permitted request is handled by a thread of its own, at most ``max_clients`` at
    once (more are answered "busy"). ``privileged_uids`` may send every command (default: root
    and the daemon's effective uid); other peers only ``read_only`` ones. ``group`` (default:
    ``$GRASSD_CONTROL_GROUP``, if set) is the group the socket file is handed to.
    """

    def __init__(self, path: str | os.PathLike[str], handler: Handler, mode: int = 0o660,
                 max_clients: int = MAX_CLIENTS, *,
                 privileged_uids: Collection[int] | None = None,
                 read_only: Collection[str] = READ_ONLY_COMMANDS,
                 group: str | int | None = None,
                 request_deadline_s: float = REQUEST_DEADLINE_S,
                 answer_deadline_s: float = ANSWER_DEADLINE_S,
                 max_pending: int = MAX_PENDING,
                 max_pending_per_uid: int = MAX_PENDING_PER_UID,
                 evict_after_s: float = EVICT_AFTER_S) -> None:
        self.path = Path(path)
        self.handler = handler
        self.mode = mode
        self.max_clients = max_clients
        self.privileged_uids = frozenset({0, os.geteuid()} if privileged_uids is None
                                         else privileged_uids)
        self.read_only = frozenset(read_only)
        self.group = group
        self.request_deadline_s = request_deadline_s
        self.answer_deadline_s = answer_deadline_s
        self.max_pending = max_pending
        self.max_pending_per_uid = max_pending_per_uid
        self.evict_after_s = evict_after_s
        self._slots = threading.BoundedSemaphore(max_clients)
        self._lock = threading.Lock()
        self._active = 0
        #: connections turned away as busy (for tests and status)
        self.refused = 0
        #: connections cut at the request deadline, or to make room for a newer one; requests
        #: refused for their peer
        self.timed_out = 0
        self.evicted = 0
        self.denied = 0
        self._pending: dict[int, _Pending] = {}
        self._per_uid: dict[int, int] = {}
        self._sock: socket.socket | None = None
        self._sel: selectors.BaseSelector | None = None
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._accept_warned = -math.inf
        self._denied_warned: dict[int, float] = {}  # uid -> when its refusal was last logged

    @property
    def active(self) -> int:
        """Requests being handled (or their answers sent) right now."""
        with self._lock:
            return self._active

    @property
    def pending(self) -> int:
        """Connections whose request is still being read."""
        return len(self._pending)

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
        self._hand_to_group()
        sock.listen(64)
        sock.setblocking(False)
        self._sock = sock
        self._sel = selectors.DefaultSelector()
        self._sel.register(sock, selectors.EVENT_READ, None)
        self._thread = threading.Thread(target=self._serve, name="control-socket", daemon=True)
        self._thread.start()
        return self

    def _hand_to_group(self) -> None:
        """Give the socket file to ``group`` (the readers' group), so that its members may
        connect. A failure leaves the socket to the daemon's own group (nobody else can
        connect then) and says how to fix it; the daemon goes on calibrating."""
        group = self.group if self.group is not None else os.environ.get(GROUP_ENV) or None
        if group is None:
            return
        try:
            if isinstance(group, int) or group.isdigit():
                gid = int(group)
            else:
                gid = grp.getgrnam(group).gr_gid
            os.chown(self.path, -1, gid)
        except (KeyError, OSError) as exc:
            why = "no such group" if isinstance(exc, KeyError) else exc.strerror
            log.warning("cannot give control socket %s to group %s (%s): members of that group "
                        "cannot ask for status; create the group (systemd-sysusers, see "
                        "systemd/grassd.sysusers.conf) and make the daemon's user a member, or "
                        "unset %s", self.path, group, why, GROUP_ENV)

    # ------------------------------------------------------------------ reading requests
    def _serve(self) -> None:
        """The selector loop: accept, read request lines, cut connections at their deadline.
        Nothing a client does ends it; only :meth:`stop`."""
        while not self._stop.is_set():
            try:
                self._serve_once()
            except Exception:  # a bug here must not end the socket; log and go on
                log.exception("control socket: unexpected error (still serving)")
                time.sleep(0.05)
        for p in list(self._pending.values()):
            self._drop(p)

    def _serve_once(self) -> None:
        assert self._sel is not None
        now = time.monotonic()
        wait = 0.2  # also how soon stop() is noticed
        if self._pending:
            wait = min(wait, max(0.0, min(p.deadline for p in self._pending.values()) - now))
        for key, _ in self._sel.select(wait):
            if self._stop.is_set():
                return
            if key.data is None:
                self._accept()
            else:
                self._read(key.data)
        now = time.monotonic()
        for p in [p for p in self._pending.values() if p.deadline <= now]:
            self.timed_out += 1
            self._drop(p, {"ok": False, "error": f"bad request: no complete request line "
                                                  f"within {self.request_deadline_s:g} s; send "
                                                  "one JSON object and a newline at once"})

    def _accept(self) -> None:
        assert self._sock is not None and self._sel is not None
        for _ in range(64):  # then let the others read
            try:
                conn, _ = self._sock.accept()
            except (BlockingIOError, InterruptedError):
                return
            except OSError as exc:  # EMFILE and the like: leave it in the backlog a moment
                if not self._stop.is_set():
                    if time.monotonic() - self._accept_warned > 60:  # not 20 lines a second
                        self._accept_warned = time.monotonic()
                        log.warning("control socket: accept failed: %s", exc)
                    time.sleep(0.05)
                return
            try:
                conn.setblocking(False)
                peer = peer_credentials(conn)
                if self.active >= self.max_clients:
                    self._busy(conn, f"busy: {self.max_clients} clients are being served; "
                                     "try again in a moment")
                    continue
                if not self._make_room(peer.uid):
                    self._busy(conn, f"busy: too many connections (of uid {peer.uid}) are "
                                     "still sending their request; try again in a moment")
                    continue
                p = _Pending(conn, peer, time.monotonic() + self.request_deadline_s)
                self._sel.register(conn, selectors.EVENT_READ, p)
                self._pending[conn.fileno()] = p
                self._per_uid[peer.uid] = self._per_uid.get(peer.uid, 0) + 1
            except Exception:
                log.exception("control socket: cannot take a connection")
                conn.close()

    def _make_room(self, uid: int) -> bool:
        """Whether a new connection of ``uid`` may be read: there is room, or room was made by
        cutting the oldest pending connection of ``uid`` (when ``uid`` is at its share) or of
        the user holding the most, if that one has been sending for ``evict_after_s``."""
        if self._per_uid.get(uid, 0) >= self.max_pending_per_uid:
            victim_uid = uid
        elif len(self._pending) >= self.max_pending:
            victim_uid = max(self._per_uid, key=lambda u: self._per_uid[u])
        else:
            return True
        # the dict keeps accept order: the first one of that user is its oldest
        oldest = next(p for p in self._pending.values() if p.peer.uid == victim_uid)
        if time.monotonic() - (oldest.deadline - self.request_deadline_s) < self.evict_after_s:
            return False
        self.evicted += 1
        self._drop(oldest, {"ok": False, "error": "bad request: cut to make room for newer "
                                                   "clients; send the request line at once"})
        return True

    def _read(self, p: _Pending) -> None:
        try:
            chunk = p.conn.recv(4096)
        except (BlockingIOError, InterruptedError):
            return
        except OSError:
            self._drop(p)
            return
        p.buf += chunk
        end = p.buf.find(b"\n")
        if end < 0 and len(p.buf) > MAX_REQUEST_BYTES or end > MAX_REQUEST_BYTES:
            self._drop(p, {"ok": False, "error": f"bad request: longer than "
                                                  f"{MAX_REQUEST_BYTES} bytes; a request is "
                                                  "one JSON object on one line"})
            return
        if end < 0 and chunk:
            return  # more to come (until the deadline)
        line = bytes(p.buf if end < 0 else p.buf[:end])
        self._unregister(p)
        try:
            self._dispatch(p, line)
        except Exception as exc:  # never let one request end the loop
            log.exception("control socket: cannot dispatch a request")
            self._reply_now(p.conn, {"ok": False, "error": f"internal error: {_describe(exc)}"})
            p.conn.close()

    def _dispatch(self, p: _Pending, line: bytes) -> None:
        """Parse and check ``line`` here; hand a permitted request to a thread of its own."""
        try:
            req = parse_request(line)
        except Exception as exc:  # RecursionError, MemoryError, ValueError, ... all answered
            self._reply_now(p.conn, {"ok": False, "error": f"bad request: {_describe(exc)}"})
            p.conn.close()
            return
        cmd = command(req)
        if cmd not in self.read_only and p.peer.uid not in self.privileged_uids:
            self.denied += 1
            now = time.monotonic()
            if now - self._denied_warned.get(p.peer.uid, -math.inf) > 60:  # no flood
                self._denied_warned[p.peer.uid] = now
                log.warning("control socket: %r refused for uid %d (pid %d; further refusals "
                            "of this uid within a minute are counted, not logged)", cmd[:40],
                            p.peer.uid, p.peer.pid)
            self._reply_now(p.conn, {
                "ok": False, "denied": True,
                "error": f"permission denied: {cmd[:40]!r} changes the daemon's state and is "
                         f"only for root or the daemon's user (you are uid {p.peer.uid}); "
                         f"anyone may use {', '.join(sorted(self.read_only))}"})
            p.conn.close()
            return
        if cmd not in self.read_only:
            log.info("control socket: %r from uid %d (pid %d)", cmd[:40], p.peer.uid,
                     p.peer.pid)
        if not self._slots.acquire(blocking=False):
            self._busy(p.conn, f"busy: {self.max_clients} clients are being served; try "
                               "again in a moment")
            return
        with self._lock:
            self._active += 1
        try:
            threading.Thread(target=self._handle, args=(p.conn, req), name="control-conn",
                             daemon=True).start()
        except RuntimeError:  # cannot start a thread: treat as busy
            self._release()
            self._busy(p.conn, "busy: the daemon cannot start another thread; try again")

    def _unregister(self, p: _Pending) -> None:
        assert self._sel is not None
        fd = p.conn.fileno()
        if self._pending.pop(fd, None) is None:
            return
        with contextlib.suppress(KeyError, ValueError):
            self._sel.unregister(p.conn)
        n = self._per_uid.get(p.peer.uid, 1) - 1
        if n > 0:
            self._per_uid[p.peer.uid] = n
        else:
            self._per_uid.pop(p.peer.uid, None)

    def _drop(self, p: _Pending, answer: Answer | None = None) -> None:
        """Stop reading ``p``: answer (if given, without blocking) and close."""
        self._unregister(p)
        if answer is not None:
            self._reply_now(p.conn, answer)
        p.conn.close()

    def _busy(self, conn: socket.socket, error: str) -> None:
        """Answer "busy" and close, in the selector thread, without blocking."""
        self.refused += 1
        self._reply_now(conn, {"ok": False, "busy": True, "error": error})
        conn.close()

    @staticmethod
    def _reply_now(conn: socket.socket, obj: Answer) -> None:
        """Send a short answer without blocking (it fits the empty socket buffer; a client
        whose buffer is full just misses it), then drop what the client sent that was not
        read, so that it reads the answer instead of ECONNRESET."""
        with contextlib.suppress(OSError):
            conn.setblocking(False)
            conn.send(_encode(obj))
            conn.shutdown(socket.SHUT_WR)
        with contextlib.suppress(OSError):
            for _ in range(16):
                if not conn.recv(65536):
                    break

    # ------------------------------------------------------------------ handling requests
    def _handle(self, conn: socket.socket, req: Request) -> None:
        """Run the handler (every exception becomes an error answer) and send its answer
        within :attr:`answer_deadline_s` all told; always give the slot back."""
        try:
            with conn:
                try:
                    answer = self.handler(req)
                    if not isinstance(answer, dict):
                        raise TypeError(f"handler answered {type(answer).__name__}, not a dict")
                except Exception as exc:  # reported to the client, daemon lives on
                    log.warning("control request %r failed: %s", command(req)[:40],
                                _describe(exc))
                    answer = {"ok": False, "error": _describe(exc)}
                try:
                    data = _encode(answer)
                except Exception as exc:  # unencodable answer: say so instead
                    data = _encode({"ok": False, "error": f"internal error: cannot encode the "
                                                          f"answer: {_describe(exc)}"})
                conn.setblocking(True)
                conn.settimeout(self.answer_deadline_s)  # sendall: one total deadline
                with contextlib.suppress(OSError):
                    conn.sendall(data)
        except Exception:  # nothing may escape the thread
            log.exception("control socket: unexpected error in a handler thread")
        finally:
            self._release()

    def _release(self) -> None:
        with self._lock:
            self._active -= 1
        self._slots.release()

    def stop(self) -> None:
        """Stop accepting and remove the socket file."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(2)
            if self._thread.is_alive():  # still inside a select: closing it under the thread
                log.warning("control socket: the reader thread did not stop within 2 s")
            elif self._sel is not None:
                self._sel.close()
        elif self._sel is not None:
            self._sel.close()
        if self._sock is not None:
            self._sock.close()
            self._sock = None
        with contextlib.suppress(FileNotFoundError):
            self.path.unlink()


def peer_credentials(conn: socket.socket) -> Peer:
    """The pid, uid and gid of the process at the other end of UNIX socket ``conn``
    (``SO_PEERCRED``: as it was at connect(), not what the client claims); uid -1 where the
    platform cannot tell."""
    try:
        raw = conn.getsockopt(socket.SOL_SOCKET, socket.SO_PEERCRED, _PEERCRED.size)
        pid, uid, gid = _PEERCRED.unpack(raw)
    except (AttributeError, OSError, struct.error):
        return Peer(-1, -1, -1)
    return Peer(pid, uid, gid)


def parse_request(line: bytes) -> Request:
    """Decode one request line: a JSON object with a ``"cmd"`` string. Raises
    :class:`ValueError` (or whatever the decoder raises on hostile input, e.g.
    ``RecursionError``) naming what a request must look like."""
    if not line.strip():
        raise ValueError('empty request; send one JSON object such as {"cmd": "status"}')
    req = json.loads(line)
    if not isinstance(req, dict) or not isinstance(req.get("cmd"), str):
        raise ValueError('request must be a JSON object with a "cmd" string')
    parsed: Request = req
    return parsed


def _describe(exc: BaseException) -> str:
    """A one-line description of ``exc`` for an error answer (some, like MemoryError, have
    no message)."""
    if isinstance(exc, RecursionError):
        return "nested too deeply (a request is a flat JSON object)"
    if isinstance(exc, MemoryError):
        return "out of memory"
    text = str(exc).replace("\n", " ")[:500]
    return text or type(exc).__name__


def _encode(obj: Answer) -> bytes:
    return json.dumps(obj, default=str).encode() + b"\n"


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


def _no_access_hint(path: Path) -> str:
    """How a user who may not open the socket gets access (names the socket's group)."""
    try:
        group = grp.getgrgid(os.stat(path).st_gid).gr_name
    except (KeyError, OSError):
        return ("ask the administrator for access to it (the group of the control socket, "
                "grassd-status under the shipped systemd unit)")
    return (f"to read status, join its group: `usermod -aG {group} USER` (then log in "
            "again); to change anything, run as root or as the daemon's user")


def request(path: str | os.PathLike[str], req: Request,
            timeout_s: float | None = 30.0) -> dict[str, Any]:
    """Send one request to the daemon at ``path`` and return its answer (the JSON object as
    it came; the caller reads the keys of the command's answer).

    ``timeout_s`` bounds the whole exchange (connect, send, and the answer however slowly it
    arrives; ``None``: no bound). Raises :class:`DaemonNotRunning` when nothing listens there,
    :class:`DaemonBusy` when the daemon is busy, :class:`ControlError` when the daemon answers
    ``ok: false`` (a refused command included), does not answer in time or the connection
    breaks.
    """
    deadline = None if timeout_s is None else time.monotonic() + timeout_s

    def remaining() -> float | None:
        if deadline is None:
            return None
        left = deadline - time.monotonic()
        if left <= 0:
            raise TimeoutError
        return left

    s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    try:
        s.settimeout(timeout_s)
        try:
            s.connect(str(path))
        except (FileNotFoundError, ConnectionRefusedError):
            raise DaemonNotRunning(f"no grassd daemon is listening on {path}") from None
        except TimeoutError:
            raise ControlError(f"the daemon did not accept within {timeout_s:g} s") from None
        except OSError as exc:
            if exc.errno in (errno.ENOENT, errno.ECONNREFUSED, errno.ENOTSOCK):
                raise DaemonNotRunning(f"no grassd daemon is listening on {path}") from None
            if exc.errno in (errno.EACCES, errno.EPERM):
                raise ControlError(f"no permission to talk to the daemon on {path}: "
                                   f"{_no_access_hint(Path(path))}") from None
            raise ControlError(f"cannot reach the daemon on {path}: {exc.strerror}") from None
        buf = bytearray()
        try:
            with contextlib.suppress(OSError):  # a busy daemon answers and closes before reading
                s.settimeout(remaining())
                s.sendall(json.dumps(req).encode() + b"\n")
            while b"\n" not in buf:
                s.settimeout(remaining())
                chunk = s.recv(65536)
                if not chunk:
                    break
                buf += chunk
                if len(buf) > MAX_ANSWER_BYTES:
                    raise ValueError(f"answer longer than {MAX_ANSWER_BYTES} bytes")
        except TimeoutError:
            raise ControlError(f"the daemon did not answer within {timeout_s:g} s") \
                from None
        except (OSError, ValueError) as exc:
            if buf and isinstance(exc, ConnectionResetError):
                pass  # the answer came before the reset: read it
            else:
                raise ControlError(f"bad answer from the daemon: {exc}") from None
    finally:
        s.close()
    line = bytes(buf).split(b"\n", 1)[0]
    try:
        answer = json.loads(line) if line.strip() else None
    except (ValueError, RecursionError) as exc:
        raise ControlError(f"bad answer from the daemon: {_describe(exc)}") from None
    if not isinstance(answer, dict):
        raise ControlError(f"bad answer from the daemon: {line[:200]!r}")
    if not answer.get("ok", False):
        if answer.get("busy"):
            raise DaemonBusy(f"daemon: {answer.get('error', 'busy')}")
        raise ControlError(f"daemon: {answer.get('error', 'request failed')}")
    return answer
