"""A run without a bundle that the Dask cluster could not compute, retried with backoff.

With ``[compute] scheduler`` a run is computed on a dask.distributed cluster. When the
cluster is unreachable or its worker dies (:class:`~grassd.daemon.core.errors.ComputeUnavailable`),
a bundle's run leaves the bundle waiting in processing/
(:class:`~grassd.daemon.core.runtime.bundle_pipeline.WaitingBundles`). A scheduled or requested
run has no bundle to wait, so :class:`ComputeRetry` keeps it: the last good table stays
active, health says degraded with the reason (the status's ``compute_wait``), and the run is
tried again after ``retry_s`` seconds, then doubling up to ``retry_max_s``, until a run is
computed again (any run: a bundle's too).
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass

from grassd.daemon.core.monitoring.status_types import ComputeWait

log = logging.getLogger(__name__)


@dataclass
class _Failure:
    trigger: str
    reason: str
    since: float  #: epoch s of the first failure
    attempts: int
    delay_s: float
    retry_at: float  #: monotonic s


class ComputeRetry:
    """The run waiting for the compute cluster, if any (set and cleared by the main thread,
    read by status from others: :meth:`snapshot` reads one attribute)."""

    def __init__(self, retry_s: float, retry_max_s: float) -> None:
        self.retry_s = retry_s
        self.retry_max_s = retry_max_s
        self._failure: _Failure | None = None

    def failed(self, trigger: str, reason: str) -> float:
        """A ``trigger`` run (scheduled or requested) could not be computed for ``reason``;
        returns the seconds until it is tried again (the first ``retry_s``, then doubling up
        to ``retry_max_s``)."""
        old, now = self._failure, time.monotonic()
        delay = self.retry_s if old is None else min(old.delay_s * 2, self.retry_max_s)
        self._failure = _Failure(trigger=old.trigger if old else trigger, reason=reason,
                                 since=old.since if old else time.time(),
                                 attempts=(old.attempts if old else 0) + 1, delay_s=delay,
                                 retry_at=now + delay)
        log.warning("the %s run waits for compute: %s; retried in %g s",
                    self._failure.trigger, reason, delay)
        return delay

    def computed(self) -> None:
        """A run was computed: the cluster is back (no retry pending any more)."""
        if self._failure is not None:
            log.info("compute is back after %d failed run(s)", self._failure.attempts)
            self._failure = None

    def due(self) -> str | None:
        """The trigger of the run to retry now, else None."""
        f = self._failure
        return f.trigger if f is not None and time.monotonic() >= f.retry_at else None

    def snapshot(self) -> ComputeWait | None:
        """The waiting run for status (None: nothing waits for compute)."""
        f = self._failure
        if f is None:
            return None
        return ComputeWait(trigger=f.trigger, reason=f.reason, since=f.since,
                           attempts=f.attempts,
                           retry_in_s=max(f.retry_at - time.monotonic(), 0.0))
