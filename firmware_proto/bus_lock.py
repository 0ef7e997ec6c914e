"""Turns on one serial line: :class:`BusLock`, a first-come first-served re-entrant lock.

Every request on a line (send, then wait for its answer) holds the line's lock, so several
threads (content frames, table pushes, status reads, test patterns) may share one
:class:`~grassd.firmware_proto.client.ControllerClient`. Waiters are served in the order they
came: a table push that releases the line between two chunks gets it back only after the
frame that was waiting has been sent, and a frame waits at most for the one request in flight
(PROTOCOL.md section 5, "Sharing a line").
"""

from __future__ import annotations

import threading
from collections import deque


class BusLock:
    """A re-entrant lock that hands the line to waiting threads in arrival order."""

    def __init__(self) -> None:
        self._cond = threading.Condition(threading.Lock())
        self._owner: int | None = None
        self._depth = 0
        self._queue: deque[object] = deque()

    def acquire(self) -> None:
        """Take the line, after every thread that asked before (re-entrant)."""
        me = threading.get_ident()
        with self._cond:
            if self._owner == me:
                self._depth += 1
                return
            ticket = object()
            self._queue.append(ticket)
            while self._owner is not None or self._queue[0] is not ticket:
                self._cond.wait()
            self._queue.popleft()
            self._owner, self._depth = me, 1

    def release(self) -> None:
        """Give the line back (the outermost release hands it to the next waiter)."""
        with self._cond:
            if self._owner != threading.get_ident():
                raise RuntimeError("BusLock released by a thread that does not hold it")
            self._depth -= 1
            if self._depth == 0:
                self._owner = None
                self._cond.notify_all()

    @property
    def waiting(self) -> int:
        """Threads waiting for the line now."""
        return len(self._queue)

    def __enter__(self) -> BusLock:
        self.acquire()
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()
