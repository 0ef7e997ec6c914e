"""The one thread that runs the studio's simulations (the renderer holds one scene at a time).

Requests are queued in order; each belongs to an owner (a page's WebSocket, an API call). A
newer request of the same owner supersedes the older one: a queued one is skipped, a running one
stops at its next check (between rounds of the characteristic, images, audience places), so an
input change restarts the views at once instead of waiting for stale work.

A job submitted as ``yields`` (a script's API request) gives way to the others (a page's): its
check raises :class:`Yielded` while one of them waits, and the job goes back into the queue
behind it, to go on where it stopped (a characteristic keeps its complete rounds,
:class:`~grassd.daemon.calibration.simulation.CurveRun`). So a script's long request does not
hold a page's inputs back; it waits while a page keeps changing.
"""

from __future__ import annotations

import itertools
import logging
import queue
import threading
from collections.abc import Callable
from concurrent.futures import Future
from typing import Any

log = logging.getLogger(__name__)


class Superseded(Exception):
    """A newer request of the same owner came in (or the owner left): this one stops."""


class Yielded(Exception):  # noqa: N818 (what happened to the job, as Superseded says)
    """A job that yields stops for one that does not, and goes back into the queue."""


Check = Callable[[], None]


class Worker:
    """A daemon thread running submitted jobs ``fn(check)`` one at a time; ``check()`` raises
    :class:`Superseded` once the job's owner has submitted a newer one or was cancelled."""

    def __init__(self, name: str = "grassd-studio-worker") -> None:
        self._queue: queue.Queue = queue.Queue()
        self._latest: dict[Any, int] = {}
        self._queued: dict[Any, int] = {}  # jobs of each owner not yet finished
        self._waiting = 0  # queued jobs that do not yield
        self._ids = itertools.count(1)
        self._lock = threading.Lock()
        self._thread = threading.Thread(target=self._loop, name=name, daemon=True)
        self._thread.start()

    def submit(self, owner: Any, fn: Callable[[Check], Any], *, yields: bool = False) -> Future:
        """Queue ``fn`` for ``owner``, superseding the owner's earlier jobs; returns its
        future (its exception is :class:`Superseded` when a newer job replaced it). ``yields``:
        the job gives way to those that do not (see the module docstring); ``fn`` is then
        called again after each :class:`Yielded`, and must go on from what it kept."""
        fut: Future = Future()
        with self._lock:
            job = next(self._ids)
            self._latest[owner] = job
            self._queued[owner] = self._queued.get(owner, 0) + 1
            self._waiting += not yields
        self._queue.put((owner, job, fn, fut, yields))
        return fut

    def cancel(self, owner: Any) -> None:
        """Stop the owner's queued and running jobs (its page went away)."""
        with self._lock:
            if self._queued.get(owner):
                self._latest[owner] = -1
            else:
                self._latest.pop(owner, None)

    def cancel_all(self) -> None:
        """Stop every owner's queued and running jobs (the studio is ending)."""
        with self._lock:
            for owner in list(self._latest):
                self._latest[owner] = -1

    def _finished(self, owner: Any) -> None:
        """One job of ``owner`` is done: forget the owner when it has no other."""
        with self._lock:
            left = self._queued.get(owner, 1) - 1
            if left > 0:
                self._queued[owner] = left
            else:
                self._queued.pop(owner, None)
                self._latest.pop(owner, None)

    def stop(self) -> None:
        """End the thread after the jobs already queued."""
        self._queue.put(None)
        self._thread.join(timeout=30)

    def _current(self, owner: Any, job: int) -> bool:
        with self._lock:
            return self._latest.get(owner) == job

    def _loop(self) -> None:
        while True:
            item = self._queue.get()
            if item is None:
                return
            owner, job, fn, fut, yields = item
            if not yields:
                with self._lock:
                    self._waiting -= 1
            if not fut.running() and not fut.set_running_or_notify_cancel():
                continue

            def check(owner=owner, job=job, yields=yields) -> None:
                if not self._current(owner, job):
                    raise Superseded("a newer request replaced this one")
                if yields and self._waiting:
                    raise Yielded("a page's request goes first")

            try:
                check()
                result = fn(check)
            except Yielded:  # behind the jobs that wait, to go on after them
                self._queue.put(item)
                continue
            except BaseException as exc:  # handed to the waiting side through the future
                if not isinstance(exc, Superseded):
                    log.debug("studio job failed: %r", exc)
                self._finished(owner)
                fut.set_exception(exc)
            else:
                self._finished(owner)
                fut.set_result(result)
