"""The one thread that runs the studio's simulations (the renderer holds one scene at a time).

Each request belongs to an owner (a page's WebSocket, an API call). A newer request of the same
owner supersedes the older one: a queued one is skipped, a running one stops at its next check
(between rounds of the characteristic, images, audience places), so an input change restarts
the views at once instead of waiting for stale work.

The owners take turns (round robin), not one queue in order of arrival: a page whose job has
run for its slice (:attr:`Worker.slice_s`) while another page's job waits gives way at its next
check (:class:`Yielded`), and goes on after the others have had theirs, from what it kept (a
characteristic's complete rounds, an image's passes); its next slice is twice as long (up to
:data:`MOST_DOUBLINGS` times), so that a job whose steps are long ends however many pages
wait. In the simulator process the server moves the interrupt word every half slice while
several owners have jobs (:mod:`grassd.daemon.studio.process`), so a launch in flight reaches
a check then and not only at its round's end. So one page's costly input does not hold another
page's first curve back.

A job submitted as ``yields`` (a script's API request) gives way to the others (a page's) at
once: its check raises :class:`Yielded` while one of them waits, and the job goes back behind
it, to go on where it stopped (a characteristic keeps its complete rounds,
:class:`~grassd.daemon.core.calibration.simulation.CurveRun`). So a script's long request does not
hold a page's inputs back; it waits while a page keeps changing. Scripts take turns among
themselves as pages do.
"""

from __future__ import annotations

import itertools
import logging
import threading
import time
from collections import OrderedDict, deque
from collections.abc import Callable, Hashable
from concurrent.futures import Future
from dataclasses import dataclass
from typing import Generic, TypeVar

log = logging.getLogger(__name__)

#: Seconds a page's job runs, while another page's waits, before it gives way (the default of
#: :attr:`~grassd.daemon.studio.limits.StudioLimits.slice_s`).
SLICE_S: float = 1.0
#: Most times a job's slice doubles (at each turn it gives): a job then runs at most
#: ``2**MOST_DOUBLINGS`` slices at a turn, so another page waits at most that long for its
#: own, and a job whose step takes longer than a slice (a round of many lengths, an
#: audience map: lost when it gives way) still ends.
MOST_DOUBLINGS: int = 3


class Superseded(Exception):
    """A newer request of the same owner came in (or the owner left): this one stops."""


class Yielded(Exception):  # noqa: N818 (what happened to the job, as Superseded says)
    """A job gives way to another owner's, and goes back to wait for its turn."""


Check = Callable[[], None]
_Result = TypeVar("_Result")


@dataclass
class _Job(Generic[_Result]):
    """A submitted job: its owner, its id, the function, its future, whether it yields to
    pages (a script's), and how many turns it has given (its slice doubles with each)."""

    owner: Hashable
    job: int
    fn: Callable[[Check], _Result]
    fut: Future[_Result]
    yields: bool
    turns: int = 0


class Worker:
    """A daemon thread running submitted jobs ``fn(check)`` one at a time, the owners in turn;
    ``check()`` raises :class:`Superseded` once the job's owner has submitted a newer one or was
    cancelled, and :class:`Yielded` when the job is to give way (see the module docstring).
    ``slice_s``: seconds a job runs while another owner's of its kind waits."""

    def __init__(self, name: str = "grassd-studio-worker", slice_s: float = SLICE_S) -> None:
        self.slice_s = slice_s
        #: owners with jobs waiting, in the order of their turns
        self._owners: OrderedDict[Hashable, deque[_Job]] = OrderedDict()
        self._latest: dict[Hashable, int] = {}
        self._queued: dict[Hashable, int] = {}  # jobs of each owner not yet finished
        self._ids = itertools.count(1)
        self._lock = threading.Condition()
        self._stopping = False
        self._thread = threading.Thread(target=self._loop, name=name, daemon=True)
        self._thread.start()

    def submit(self, owner: Hashable, fn: Callable[[Check], _Result], *, yields: bool = False
               ) -> Future[_Result]:
        """Queue ``fn`` for ``owner``, superseding the owner's earlier jobs; returns its
        future (its exception is :class:`Superseded` when a newer job replaced it). ``yields``:
        the job gives way to those that do not (see the module docstring). A job that gives
        way is called again at its next turn, and must go on from what it kept."""
        fut: Future[_Result] = Future()
        with self._lock:
            item = _Job(owner, next(self._ids), fn, fut, yields)
            self._latest[owner] = item.job
            self._queued[owner] = self._queued.get(owner, 0) + 1
            self._owners.setdefault(owner, deque()).append(item)
            self._lock.notify()
        return fut

    def cancel(self, owner: Hashable) -> None:
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

    def waiting(self) -> int:
        """Owners whose newest job waits for its turn (not one superseded or cancelled)."""
        with self._lock:
            return sum(self._waits(o, pages_only=False) for o in self._owners)

    def stop(self) -> None:
        """End the thread after the jobs already queued."""
        with self._lock:
            self._stopping = True
            self._lock.notify()
        self._thread.join(timeout=30)

    # ------------------------------------------------------------------ the thread's side
    def _waits(self, owner: Hashable, *, pages_only: bool) -> bool:
        """Whether ``owner`` has a current job waiting (a page's, with ``pages_only``); under
        the lock."""
        jobs = self._owners.get(owner)
        if not jobs:
            return False
        latest = self._latest.get(owner)
        return any(j.job == latest and not (pages_only and j.yields) for j in jobs)

    def _finished(self, owner: Hashable) -> None:
        """One job of ``owner`` is done: forget the owner when it has no other. Under the
        lock."""
        left = self._queued.get(owner, 1) - 1
        if left > 0:
            self._queued[owner] = left
        else:
            self._queued.pop(owner, None)
            self._latest.pop(owner, None)

    def _take(self) -> _Job | None:
        """The next job to run (a page's before a script's, the owners in turn), each stale
        one met on the way ended as superseded; None when the worker is stopping and nothing
        is left. Blocks until there is one."""
        with self._lock:
            while True:
                for pages in (True, False):
                    for owner in list(self._owners):
                        jobs = self._owners[owner]
                        while jobs and jobs[0].job != self._latest.get(owner):
                            stale = jobs.popleft()
                            self._finished(owner)
                            if stale.turns or stale.fut.set_running_or_notify_cancel():
                                stale.fut.set_exception(
                                    Superseded("a newer request replaced this one"))
                        if not jobs:
                            del self._owners[owner]
                            continue
                        if pages and jobs[0].yields:
                            continue
                        item = jobs.popleft()
                        del self._owners[owner]
                        if jobs:  # newer ones behind it: its turn comes again
                            self._owners[owner] = jobs
                        return item
                if self._stopping:
                    return None
                self._lock.wait()

    def _gives_way(self, item: _Job, started: float) -> bool:
        """Whether the running ``item`` is to give way now (under the lock): a script's to any
        page that waits; any job whose slice is over to another owner of its kind that waits."""
        others = [o for o in self._owners if o != item.owner]
        if item.yields and any(self._waits(o, pages_only=True) for o in others):
            return True
        if time.monotonic() - started < self.slice_s * 2 ** min(item.turns, MOST_DOUBLINGS):
            return False
        return any(self._waits(o, pages_only=not item.yields) for o in others)

    def _loop(self) -> None:
        while True:
            item = self._take()
            if item is None:
                return
            if not item.turns and not item.fut.set_running_or_notify_cancel():
                with self._lock:
                    self._finished(item.owner)
                continue
            started = time.monotonic()

            def check(item=item, started=started) -> None:
                with self._lock:
                    if self._latest.get(item.owner) != item.job:
                        raise Superseded("a newer request replaced this one")
                    if self._gives_way(item, started):
                        raise Yielded("another page's request takes its turn")

            try:
                check()
                result = item.fn(check)
            except Yielded:  # behind the others, to go on at its next turn
                with self._lock:
                    item.turns += 1
                    jobs = self._owners.pop(item.owner, deque())
                    jobs.appendleft(item)
                    self._owners[item.owner] = jobs  # the owner's turn comes last
                continue
            except BaseException as exc:  # handed to the waiting side through the future
                if not isinstance(exc, Superseded):
                    log.debug("studio job failed: %r", exc)
                with self._lock:
                    self._finished(item.owner)
                item.fut.set_exception(exc)
            else:
                with self._lock:
                    self._finished(item.owner)
                item.fut.set_result(result)
