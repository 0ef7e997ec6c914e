"""The state directory's lock: one grassd process at a time writes a state directory.

``grassd run`` and ``grassd calibrate --now`` (when it runs the calibration itself) take an
exclusive ``flock(2)`` on ``<state_dir>/grassd.lock`` for as long as they run and write their
PID and command into it. A second one fails at once with
:class:`~grassd.daemon.core.errors.StateDirLocked` naming the holder's PID, instead of both writing
the database, the inbox directories and the controllers at the same time (e.g. a one-shot
started while the daemon is still initialising, before its control socket answers).

Commands that only need the state directory to be free of a daemon (``grassd controllers``
talking on a serial bus the daemon owns) use :meth:`StateLock.shared`: a shared lock on the
lock file if it exists, creating nothing, so that they run as any user and a daemon starting
meanwhile is refused until they are done. The daemon also lists the serial ports it owns in
the lock file (:meth:`StateLock.note_ports`), so such a command on another port (a spare
controller on a bench adapter) is let through while the daemon runs.

The kernel drops the lock when the holder exits, however it exits, so a stale lock file never
blocks anybody (the file itself is left in place: unlinking it would let two processes lock two
different files).
"""

from __future__ import annotations

import contextlib
import fcntl
import logging
import os
import sys
import time
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path

from grassd.daemon.core.errors import StateDirLocked, StateDirUnwritable
from grassd.daemon.core.store.atomic import describe_write_error
from grassd.daemon.core.store.layout import LOCK_NAME

log = logging.getLogger(__name__)



def command_line() -> str:
    """A short name for this process's command (e.g. ``grassd run``)."""
    args = [os.path.basename(sys.argv[0] or "python")] + [a for a in sys.argv[1:3]
                                                           if not a.startswith("-")]
    return " ".join(args)


def _alive(pid: int) -> bool:
    """True when process ``pid`` exists (signal 0 probes without sending anything)."""
    if pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # it exists, owned by another user
        pass
    return True


class StateLock:
    """Exclusive lock on ``state_dir``/``name`` (grassd.lock: the state directory's; the
    capture station locks its camera with another name); ``what`` describes the holder."""

    def __init__(self, state_dir: str | os.PathLike[str], what: str | None = None,
                 name: str = LOCK_NAME) -> None:
        self.path = Path(state_dir) / name
        self.what = what or command_line()
        self._fd: int | None = None

    @property
    def held(self) -> bool:
        """True while this object holds the lock."""
        return self._fd is not None

    def holder(self) -> tuple[int | None, str]:
        """(PID, command) written by the current holder; (None, "") if unreadable, or when
        that PID no longer runs (a holder killed with SIGKILL leaves its PID behind, and a
        shared holder, :meth:`shared`, writes none)."""
        for _ in range(20):  # the holder writes right after locking: give it a moment
            with contextlib.suppress(OSError, ValueError):
                text = self.path.read_text().strip()
                if text:
                    pid, _, what = text.splitlines()[0].partition(" ")
                    return (int(pid), what) if _alive(int(pid)) else (None, "")
            time.sleep(0.01)
        return None, ""

    def holder_name(self, unknown: str) -> str:
        """The holder for a message, e.g. "grassd run (PID 12)"; ``unknown`` when its PID is
        not known (:meth:`holder`)."""
        pid, what = self.holder()
        return f"{what or 'grassd'} (PID {pid})" if pid else unknown

    def note_ports(self, ports: list[str]) -> None:
        """Write the serial ports this holder owns (resolved paths) after its PID line, for
        :meth:`holder_ports`; a failed write is logged, the lock holds all the same."""
        if self._fd is None:
            return
        try:
            self._write_holder(ports)
        except OSError as exc:
            log.warning("cannot note the serial ports in %s (%s)", self.path, exc)

    def _write_holder(self, ports: Sequence[str] = ()) -> None:
        """Replace the held lock file's text by "PID command" and a "port PATH" line per
        serial port (resolved) this holder owns; raises OSError."""
        lines = [f"{os.getpid()} {self.what}"] + [f"port {os.path.realpath(p)}" for p in ports]
        os.ftruncate(self._fd, 0)
        os.pwrite(self._fd, ("\n".join(lines) + "\n").encode(), 0)

    def holder_ports(self) -> set[str] | None:
        """Resolved serial ports the current holder owns, or None when it listed none (an
        older grassd): then any port may be its."""
        with contextlib.suppress(OSError):
            ports = {line[5:] for line in self.path.read_text().splitlines()
                     if line.startswith("port ")}
            return ports or None
        return None

    def acquire(self) -> StateLock:
        """Take the lock or raise :class:`StateDirLocked` naming the holder's PID
        (:class:`StateDirUnwritable` when the lock file cannot be created or opened)."""
        if not self.try_acquire():
            who = self.holder_name("another grassd process (e.g. a `grassd controllers` "
                                   "command)")
            raise StateDirLocked(
                f"state directory {self.path.parent} is in use by {who}: stop it first, or "
                "let it finish (`grassd calibrate --now` asks a running daemon over its control "
                "socket)")
        return self

    def try_acquire(self) -> bool:
        """Take the lock and note this holder in it, or return False when another holds it
        (:class:`StateDirUnwritable` when the lock file cannot be created or opened)."""
        if self._fd is not None:
            return True
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
        except OSError as exc:  # read-only file system, another user's directory, ...
            raise StateDirUnwritable(
                describe_write_error(exc, self.path) + " (grassd keeps its state there: "
                "run it as the user owning the state directory, or choose another with "
                "--state-dir / state_dir)") from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            return False
        except BaseException:
            os.close(fd)
            raise
        self._fd = fd
        try:  # who holds it, for the message of a second one; the flock is the lock
            self._write_holder()
        except OSError as exc:  # e.g. a full disk: the daemon must still (re)start
            log.warning("cannot note PID %d in %s (%s); the lock holds all the same",
                        os.getpid(), self.path, exc)
        return True

    @contextlib.contextmanager
    def shared(self, refuse: Callable[[str], str],
               port: str | None = None) -> Iterator[None]:
        """Hold a shared lock on the lock file while the block runs, or raise
        :class:`StateDirLocked` with ``refuse(holder)`` (``holder`` e.g. "grassd run (PID 12)")
        when a grassd process holds it exclusively, unless ``port`` is given and is not one
        of the serial ports the holder listed (:meth:`holder_ports`): then the block runs
        without the lock.

        Creates nothing: without a lock file (no grassd ever ran on this state directory) the
        block runs unlocked. :class:`StateDirUnwritable` when the lock file exists but cannot be
        opened (then whether a daemon runs cannot be told).
        """
        try:
            fd = os.open(self.path, os.O_RDONLY | os.O_CLOEXEC)
        except (FileNotFoundError, NotADirectoryError):
            yield
            return
        except OSError as exc:
            raise StateDirUnwritable(
                f"cannot open {self.path} to check that no grassd daemon uses the state "
                f"directory: {exc.strerror or exc}: run as the daemon's user or root") from None
        try:
            try:
                fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
            except BlockingIOError:
                owned = self.holder_ports()
                if port is None or owned is None or os.path.realpath(port) in owned:
                    raise StateDirLocked(refuse(self.holder_name("another grassd process"))
                                         ) from None
            yield
        finally:
            os.close(fd)

    def release(self) -> None:
        """Drop the lock (closing the file releases the flock)."""
        if self._fd is not None:
            with contextlib.suppress(OSError):
                os.ftruncate(self._fd, 0)
            os.close(self._fd)
            self._fd = None

    def __enter__(self) -> StateLock:
        return self.acquire()

    def __exit__(self, *exc: object) -> None:
        self.release()
