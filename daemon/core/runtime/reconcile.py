"""Reconcile, the one code path that pushes tables: every controller that does not report its
desired table gets it (its own table when the run made one per controller, the run's
display-wide table otherwise). The desired tables are one
:class:`~grassd.daemon.core.hardware.desired_tables.DesiredTables` value: the one the commit
wrote, or, at start and after the current run or the controllers changed, the one made from
the history."""

from __future__ import annotations

import logging
import threading
from collections.abc import Sequence
from enum import Enum

from grassd.daemon.core.config.settings import ControllerConfig
from grassd.daemon.core.hardware.desired_tables import DesiredTables
from grassd.daemon.core.hardware.fleet import ControllerReport, Fleet
from grassd.daemon.core.runtime.push_outcomes import PushOutcomes
from grassd.daemon.core.runtime.status import desired_from_history
from grassd.daemon.core.store.history import History

log = logging.getLogger(__name__)


class PushKind(Enum):
    """Why reconcile runs: right after a commit (the run's own push: every controller is
    tried at once, whatever its backoff, and every outcome is recorded) or as the main loop's
    periodic reconcile (with the backoff; a streak of failures recorded sparsely)."""

    #: a run's own push, right after its commit (history rows of kind "push")
    PUSH = "push"
    #: the main loop's reconcile (history rows of kind "reconcile")
    RECONCILE = "reconcile"


class CurrentDesired:
    """The :class:`DesiredTables` of the current table in ``history`` for the configured
    controllers: the value the commit wrote (:meth:`wrote`), or one made from the history
    when the current run or the controllers differ from those it was made for. Safe to read
    from another thread (the value and its key are replaced together)."""

    def __init__(self, history: History) -> None:
        self.history = history
        self._value: tuple[tuple[int, tuple[ControllerConfig, ...]] | None,
                           DesiredTables | None] = (None, None)

    def wrote(self, desired: DesiredTables, controllers: Sequence[ControllerConfig]) -> None:
        """The commit made ``desired`` the current table for ``controllers``."""
        assert desired.run_id is not None
        self._value = ((desired.run_id, tuple(controllers)), desired)

    def current(self, controllers: Sequence[ControllerConfig]) -> DesiredTables | None:
        """The desired tables now (None: no run made a table yet); one query of the history
        to check that its current run is still the one the value was made for."""
        cur = self.history.current_table()
        if cur is None:
            return None
        key = (cur.id, tuple(controllers))
        value = self._value
        if value[0] != key:
            value = (key, desired_from_history(self.history, cur, controllers))
            self._value = value
        return value[1]


def reconcile_controllers(desired: DesiredTables | None, fleet: Fleet, outcomes: PushOutcomes,
                          stop: threading.Event, kind: PushKind = PushKind.RECONCILE
                          ) -> list[ControllerReport]:
    """Push ``desired`` to every controller of ``fleet`` that does not report it and record
    the outcomes. ``kind`` PUSH (right after the commit): every controller is tried at once
    and every outcome recorded; RECONCILE: with the backoff, and a streak of failures
    recorded sparsely (:class:`PushOutcomes`). Stops between controllers once ``stop`` is
    set. Nothing is desired yet (None): nothing to do."""
    if desired is None:
        return []
    after_commit = kind is PushKind.PUSH
    reports = fleet.apply(desired, stop=stop, hold=not after_commit)
    for r in reports:
        if after_commit:
            outcomes.record(r, desired.run_id, kind.value)
            continue
        if r.ok and not r.pushed:  # holds its table (again): any failure streak is over
            outcomes.holds_its_table(r.controller)
        if r.pushed:
            outcomes.record(r, desired.run_id, kind.value)
            if r.ok:
                log.info("controller %s reconciled to table %d", r.controller,
                         desired.table_id)
        else:
            outcomes.note(r)
    return reports
