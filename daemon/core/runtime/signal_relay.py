"""Signals turned into actions outside the signal handler.

Python runs a signal handler in the main thread between two bytecodes, wherever that thread
is: also inside :meth:`threading.Event.wait`, holding the lock of the event's condition. A
handler that calls ``event.set()`` on that same event then waits for a lock its own thread
holds, and the daemon hangs in its SIGTERM handler. So a handler here only does what takes
no lock: it notes a stop signal in a plain flag and writes the signal's number, one byte, to
a non-blocking self-pipe. A thread of its own (``signal-relay``) reads the pipe and runs the
action of each signal (``stop_event.set()``, ``reload_event.set()``), as any other thread
would.

A burst of signals cannot lose a stop: when the pipe is full the byte is dropped, but the flag
is set, and the relay, woken by the bytes already waiting, runs the stop action for it.
"""

from __future__ import annotations

import contextlib
import logging
import os
import signal
import threading
from collections.abc import Callable, Iterable, Mapping
from types import FrameType

log = logging.getLogger(__name__)


class SignalRelay:
    """Runs ``actions[signum]()`` in a relay thread for each signal received.

    ``latched``: the signals whose action, once one arrived, runs again at every wake-up
    (stop signals: see the module docstring). :meth:`install` (main thread only) sets the
    handlers and starts the thread; :meth:`close` stops it (a signal that arrives later is
    ignored, unless ``restore`` gave the previous handlers back).
    """

    def __init__(self, actions: Mapping[int, Callable[[], None]],
                 latched: Iterable[int] = ()) -> None:
        self.actions = dict(actions)
        self.latched = frozenset(latched) & set(self.actions)
        self._arrived: set[int] = set()  # latched signals seen; only the handler adds
        self._wfd = -1
        self._rfd = -1
        self._previous: dict[int, object] = {}
        self._thread: threading.Thread | None = None

    def install(self) -> SignalRelay:
        """Open the pipe, start the relay thread and install the handlers (from the main
        thread, as :func:`signal.signal` requires). Returns ``self``."""
        rfd, wfd = os.pipe2(os.O_CLOEXEC)
        os.set_blocking(wfd, False)  # the handler never blocks on a full pipe
        self._rfd, self._wfd = rfd, wfd
        self._thread = threading.Thread(target=self._relay, args=(rfd,), daemon=True,
                                        name="signal-relay")
        self._thread.start()
        for signum in self.actions:
            self._previous[signum] = signal.signal(signum, self._handler)
        return self

    def _handler(self, signum: int, frame: FrameType | None) -> None:
        """The signal handler: a flag and a byte, nothing that takes a lock."""
        if signum in self.latched:
            self._arrived.add(signum)
        fd = self._wfd
        if fd >= 0:
            with contextlib.suppress(OSError):  # full (see the module docstring) or closed
                os.write(fd, bytes((signum & 0xFF,)))

    def _relay(self, rfd: int) -> None:
        """The relay thread: run the action of every signal byte until the pipe closes."""
        try:
            while True:
                try:
                    data = os.read(rfd, 512)
                except InterruptedError:
                    continue
                except OSError:  # the pipe is gone: nothing more can arrive
                    log.exception("the signal relay's pipe failed; signals are no longer relayed")
                    return
                if not data:
                    return  # closed
                # tuple(): one C-level copy, so a handler adding meanwhile cannot break it
                for signum in dict.fromkeys([*data, *tuple(self._arrived)]):  # in order, once
                    self._run(signum)
        finally:
            os.close(rfd)

    def _run(self, signum: int) -> None:
        action = self.actions.get(signum)
        if action is None:
            return
        try:
            action()
        except Exception:  # an action must not end the relay: later signals still count
            log.exception("the action for signal %d failed", signum)

    def close(self, restore: bool = False, timeout_s: float = 5.0) -> None:
        """Stop relaying (main thread): later signals are ignored, or with ``restore``
        handled by the handlers there were before :meth:`install`."""
        if restore:
            for signum, previous in self._previous.items():
                signal.signal(signum, previous)  # type: ignore[arg-type]
        wfd, self._wfd = self._wfd, -1  # the handler sees -1 before the fd is closed
        if wfd >= 0:
            os.close(wfd)  # the relay reads EOF and ends
        if self._thread is not None:
            self._thread.join(timeout_s)
            self._thread = None
