"""The daemon's health as one of three levels, for alerts, metrics and the status page.

:func:`assess` reads a :class:`~grassd.daemon.core.monitoring.status_types.Status` (what
:meth:`grassd.daemon.core.runtime.service.Service.status` or
:func:`grassd.daemon.core.runtime.status.collect_status` returns) and answers

- ``ok``: a table is active and every controller reports it, nothing waits on an error;
- ``degraded``: the display works but something needs a look: some controllers do not hold
  the active table, there is no table yet, a main-loop pass survived an error (full disk,
  database), a reload was refused, a bundle waits for the lux sensor or the Dask cluster, a
  scheduled or requested run waits for the Dask cluster, or the capture station's last capture
  failed (after its retries);
- ``failed``: the display is not calibrated: no controller holds the active table, or no table
  exists although runs were tried (every one failed or was rejected).

Each level comes with the reasons, one line each, naming what to look at.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # the status computes its health with assess: imported there at run time
    from grassd.daemon.core.monitoring.status_types import Status

#: The levels, best first; a level's index is its severity (the ``grassd_health`` metric).
LEVELS = ("ok", "degraded", "failed")


@dataclass(frozen=True)
class Health:
    """A health ``level`` (one of :data:`LEVELS`) and the ``reasons`` for it (empty for ok)."""

    level: str
    reasons: tuple[str, ...] = ()

    @property
    def severity(self) -> int:
        """0 ok, 1 degraded, 2 failed."""
        return LEVELS.index(self.level)

    def summary(self) -> str:
        """One line: ``ok``, or the level and its reasons (``degraded: no table yet``), as
        ``grassd status`` prints it and its JSON carries it in ``health``."""
        return self.level if not self.reasons else f"{self.level}: {'; '.join(self.reasons)}"


def assess(status: Status) -> Health:
    """The health level of ``status`` (see the module docstring) with its reasons: the one
    verdict that `grassd status`, the metrics, the alerts and the status page show (a
    :class:`~grassd.daemon.core.monitoring.status_types.Status` carries it as ``health``)."""
    failed: list[str] = []
    degraded: list[str] = []
    desired = status.desired_table
    controllers = status.controllers
    if desired is None:
        counts = status.run_counts
        tried = counts.failed + counts.rejected
        if tried and not counts.ok:
            failed.append(f"no table: all {tried} run(s) so far failed or were rejected")
        else:
            degraded.append("no table yet")
    else:
        bad = [c for c in controllers if not c.in_sync]
        for c in bad:
            err = f": {c.error}" if c.error else ""
            (failed if len(bad) == len(controllers) else degraded).append(
                f"controller {c.name} {c.state} (table {c.table_id}, not "
                f"{desired.table_id}){err}")
    live = status.daemon
    if live is not None:
        if live.last_error:
            degraded.append(f"error: {live.last_error}")
        if live.reload_error:
            degraded.append(f"reload refused: {live.reload_error}")
        for w in live.waiting_bundles:
            degraded.append(f"bundle {w.bundle} waits: {w.reason}")
        if (cw := live.compute_wait) is not None:
            degraded.append(f"{cw.trigger} run waits for compute ({cw.attempts} failed, retry "
                            f"in {cw.retry_in_s:.0f} s): {cw.reason}")
        capture = live.capture or {}
        if capture.get("last_error"):  # the light stops arriving: the table goes stale
            degraded.append(f"capture station {capture['camera']}: {capture['last_error']}")
    if failed:
        return Health("failed", tuple(failed + degraded))
    if degraded:
        return Health("degraded", tuple(degraded))
    return Health("ok")
