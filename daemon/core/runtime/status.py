"""What the daemon's status shows: :func:`collect_status` builds a
:class:`~grassd.daemon.core.monitoring.status_types.Status` from the state database alone (what
`grassd status` prints without a daemon) or, given the running daemon's live state, the live
status the control socket answers; the own tables of a run that the configured controllers
can take, and the process's resident memory."""

from __future__ import annotations

import os
import resource
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING

from grassd.daemon.core.config.settings import Config, ControllerConfig
from grassd.daemon.core.monitoring.status_json import PushRetryJson
from grassd.daemon.core.monitoring.status_types import (
    ControllerStatus,
    DaemonState,
    DesiredTable,
    PushRetry,
    RunCounts,
    RunSummary,
    Status,
    run_r2,
)
from grassd.daemon.core.store.history import ControllerTable, History, RunRecord
from grassd.daemon.core.store.quarantine import quarantined

if TYPE_CHECKING:  # the tables (numpy) only where a daemon reconciles: ``grassd status``
    # without one reads the CRCs from the database
    from grassd.daemon.core.hardware.desired_tables import DesiredTables


def rss_mb() -> float:
    """Resident set size of this process in MiB (from /proc/self/statm)."""
    try:
        with open("/proc/self/statm") as fh:
            pages = int(fh.read().split()[1])
        return pages * os.sysconf("SC_PAGE_SIZE") / 2**20
    except OSError:
        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def usable_run_tables(history: History, run_id: int,
                      controllers: Sequence[ControllerConfig]) -> dict[str, ControllerTable]:
    """The own tables of run ``run_id`` (:meth:`History.run_tables`) that the configured
    ``controllers`` can take: a per-pixel (n, 256) table only while its controller still drives
    n pixels (after a config change it would refuse it at every reconcile); such a controller,
    like one the run has no table for, gets the run's display-wide table until the next run."""
    n_pixels = {c.name: sum(b - a + 1 for a, b in c.pixels) for c in controllers}
    return {k: t for k, t in history.run_tables(run_id).items()
            if t.lengths_um.ndim == 1 or n_pixels.get(k, t.lengths_um.shape[0])
            == t.lengths_um.shape[0]}


def desired_from_history(history: History, cur: RunRecord,
                         controllers: Sequence[ControllerConfig]) -> DesiredTables:
    """The desired tables of run ``cur`` (the current table, :meth:`History.current_table`)
    for ``controllers``: its display-wide table and the own tables they can take
    (:func:`usable_run_tables`), with the CRCs their commit computed and stored (computed
    here only for a row stored without one)."""
    from grassd.daemon.core.hardware.desired_tables import CheckedTable, DesiredTables

    lengths = cur.lengths_um or ()
    display = (CheckedTable.of(lengths) if cur.table_crc is None
               else CheckedTable.stored(lengths, cur.table_crc))
    own = {k: CheckedTable.stored(t.lengths_um, t.table_crc)
           for k, t in usable_run_tables(history, cur.id, controllers).items()}
    table_id = cur.id if cur.table_id is None else cur.table_id
    return DesiredTables.stored(table_id, display, own, run_id=cur.id)


def collect_status(history: History, cfg: Config, runs: int = 5, *,
                   push_backoff: Mapping[str, PushRetryJson] | None = None,
                   daemon: DaemonState | None = None,
                   desired: DesiredTables | None = None) -> Status:
    """The status from the state database (what `grassd status` shows without a daemon), its
    ``runs`` newest runs listed; a running daemon adds its live state (``daemon``), the
    tables it reconciles to (``desired``; without it they are made from the history) and its
    controllers' push backoff (``push_backoff``: name -> :meth:`Fleet.backoff`'s entry), shown
    as a controller's ``push_retry`` while it is not in sync."""
    if desired is not None:
        own = desired.own_crcs()
        shown = None if desired.display is None or desired.run_id is None else DesiredTable(
            table_id=desired.table_id, table_crc=desired.display.crc, run_id=desired.run_id,
            per_controller=own or None)
    else:  # from the database: the CRCs stored at the commit
        cur = history.current_table()
        own = {} if cur is None else {k: t.table_crc for k, t in usable_run_tables(
            history, cur.id, cfg.controllers).items()}
        shown = None if cur is None else DesiredTable(
            table_id=cur.table_id, table_crc=cur.table_crc, run_id=cur.id,
            per_controller=own or None)
    ctrls = {c.name: c for c in history.controllers()}
    wanted = [(c.name, c.port, c.address) for c in cfg.controllers]
    if ctrls and not any(name in ctrls for name, _, _ in wanted):
        # names differ (e.g. the daemon ran with --simulate-hardware): show what it recorded
        wanted = [(n, n.rsplit("#", 1)[0], int(n.rsplit("#", 1)[1])) for n in ctrls]
    backoff = push_backoff or {}
    controllers = []
    for name, port, address in wanted:
        s = ctrls.get(name)
        want_crc = None if shown is None else own.get(name, shown.table_crc)  # its own
        # table's
        in_sync = bool(s and shown and s.reachable and s.reported_id == shown.table_id
                       and s.reported_crc == want_crc)
        b = backoff.get(name)  # when a controller whose pushes fail is tried again
        controllers.append(ControllerStatus(
            name=name, port=port, address=address, reachable=bool(s and s.reachable),
            table_id=s.reported_id if s else None, table_crc=s.reported_crc if s else None,
            desired_crc=want_crc, in_sync=in_sync, last_seen=s.last_seen if s else None,
            error=s.last_error if s else None,
            push_retry=None if b is None or in_sync else PushRetry.from_json(b)))
    return Status(
        state_dir=str(cfg.state_dir), desired_table=shown, controllers=tuple(controllers),
        runs=tuple(_run_summary(r) for r in history.runs(runs)),
        run_counts=RunCounts(**{s: history.run_count(s) for s in
                                ("ok", "rejected", "failed", "superseded")}),
        quarantined=tuple(quarantined(history, cfg.light.inbox, cfg.state_dir)),
        daemon=daemon)


def _run_summary(r: RunRecord) -> RunSummary:
    m = r.metrics or {}
    return RunSummary(id=r.id, trigger=r.trigger, status=r.status, started_at=r.started_at,
                      finished_at=r.finished_at, lux=r.lux, lux_source=r.lux_source,
                      error=r.error, r2=run_r2(m), max_dev_de00=m.get("max_dev_de00"),
                      report=r.report_path, plot=r.plot_path)
