"""What the state database keeps of push outcomes: a row per push of a run, per change of a
controller's state, and of a streak of failed reconcile pushes to one controller only the
first and then one per ``failure_row_s`` (saying how many failed since when), not one per
reconcile."""

from __future__ import annotations

import time
from dataclasses import dataclass

from grassd.daemon.core.hardware.fleet import ControllerReport
from grassd.daemon.core.store.history import History
from grassd.daemon.core.timestamps import utc_iso


@dataclass
class _FailStreak:
    """Consecutive failed pushes to one controller: first failure (epoch s), the last row
    recorded (monotonic s), failures so far and how many went unrecorded since that row."""

    since: float
    last_row: float
    failures: int = 1
    unrecorded: int = 0


class PushOutcomes:
    """Records push outcomes and controller states in ``history``; a controller whose pushes
    keep failing gets one history row per ``failure_row_s`` seconds (its first failure, then
    a summary)."""

    def __init__(self, history: History, failure_row_s: float) -> None:
        self.history = history
        self.failure_row_s = failure_row_s
        self._streaks: dict[str, _FailStreak] = {}
        self._last_ctrl: dict[str, tuple] = {}

    def record(self, r: ControllerReport, run_id: int | None, kind: str) -> None:
        """Record push outcome ``r`` (``kind`` "push" or "reconcile"): always for a run's own
        push and for a change of state; of a streak of failed reconcile pushes only the first
        and then one per ``failure_row_s`` (saying how many failed since when)."""
        now = time.monotonic()
        error = r.error
        if r.ok:
            self._streaks.pop(r.controller, None)
        else:
            s = self._streaks.get(r.controller)
            if s is None:
                self._streaks[r.controller] = _FailStreak(time.time(), now)
            else:
                s.failures += 1
                if kind == "reconcile" and now - s.last_row < self.failure_row_s:
                    s.unrecorded += 1
                    self.note(r)
                    return
                since = utc_iso(s.since)
                error = (f"{r.error} ({s.failures} failed pushes since {since}, "
                         f"{s.unrecorded} not recorded)")
                s.last_row, s.unrecorded = now, 0
        self.history.record_push(run_id, r.controller, r.ok, table_id=r.table_id,
                                 table_crc=r.table_crc, error=error, kind=kind)
        self.note(r, always=True)

    def holds_its_table(self, controller: str) -> None:
        """``controller`` reports its table (again) without a push: any failure streak is
        over."""
        self._streaks.pop(controller, None)

    def note(self, r: ControllerReport, always: bool = False) -> None:
        """Store controller report ``r``'s state (reachable, reported table, error) in the
        history when it changed since the last one stored (``always``: in any case)."""
        state = (r.ok, r.reachable, r.table_id)
        if always or self._last_ctrl.get(r.controller) != state:
            self.history.set_controller(r.controller, reachable=r.reachable,
                                        reported_id=r.table_id, reported_crc=r.table_crc,
                                        error=r.error)
            self._last_ctrl[r.controller] = state
