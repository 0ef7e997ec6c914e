"""Reconcile: every controller that does not report the current table gets it (its own table
when the run made one per controller, the run's display-wide table otherwise), and the own
tables of the current run, cached between reconciles."""

from __future__ import annotations

import logging
import threading
from collections.abc import Sequence

import numpy as np

from grassd.daemon.core.config.settings import ControllerConfig
from grassd.daemon.core.hardware.fleet import ControllerReport, Fleet
from grassd.daemon.core.runtime.push_outcomes import PushOutcomes
from grassd.daemon.core.runtime.status import usable_run_tables
from grassd.daemon.core.store.history import History

log = logging.getLogger(__name__)


class OwnTables:
    """Controller name -> its own table (uint16 micrometres) of a run, from ``history``."""

    def __init__(self, history: History) -> None:
        self.history = history
        self._cache: tuple[tuple | None, dict[str, np.ndarray]] = (None, {})

    def of_run(self, run_id: int, controllers: Sequence[ControllerConfig]
               ) -> dict[str, np.ndarray]:
        """Controller name -> its own table of run ``run_id`` (empty when the run has one table
        for all; see :func:`~grassd.daemon.core.runtime.status.usable_run_tables`); cached for the
        latest run and controller configuration asked, as reconcile asks every few
        seconds."""
        key = (run_id, tuple(controllers))
        if self._cache[0] != key:
            self._cache = (key, {k: t.lengths_um for k, t in usable_run_tables(
                self.history, run_id, controllers).items()})
        return self._cache[1]


def reconcile_controllers(history: History, fleet: Fleet, own_tables: OwnTables,
              controllers: Sequence[ControllerConfig], outcomes: PushOutcomes,
              stop: threading.Event) -> list[ControllerReport]:
    """Push the current table of ``history`` to every controller of ``fleet`` that does not
    report it (its own table when the run has one per controller; the run's table to any it
    has none for) and record the outcomes. Stops between controllers once ``stop`` is set."""
    cur = history.current_table()
    if cur is None:
        return []
    own = own_tables.of_run(cur.id, controllers)
    reports = fleet.reconcile(own or cur.lengths_um, cur.table_id, stop=stop,
                              fallback=cur.lengths_um)
    for r in reports:
        if r.ok and not r.pushed:  # holds its table (again): any failure streak is over
            outcomes.holds_its_table(r.controller)
        if r.pushed:
            outcomes.record(r, cur.id, "reconcile")
            if r.ok:
                log.info("controller %s reconciled to table %d", r.controller, cur.table_id)
        else:
            outcomes.note(r)
    return reports
