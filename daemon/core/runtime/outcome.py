"""The outcome of a run, or of one attempt at a bundle: a :class:`RunStatus` and what goes
with it. :meth:`RunOutcome.to_json` is the form the control socket sends to the CLI
(``grassd calibrate --json``) and that reports keep: its keys and values are the wire format.

>>> RunOutcome(RunStatus.REJECTED, run_id=3, error="no sky").to_json()
{'status': 'rejected', 'run_id': 3, 'error': 'no sky'}
>>> RunOutcome(RunStatus.FAILED, run_id=3, error="disk full", transient=True).defer(
...     "disk full", 30.0).to_json()
{'status': 'deferred', 'run_id': 3, 'error': 'disk full', 'transient': True, 'retry_in_s': 30.0}
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from enum import StrEnum
from typing import Any, Required, TypedDict

from grassd.daemon.core.hardware.fleet import ControllerReport


class RunStatus(StrEnum):
    """How a run or an attempt at a bundle ended (the ``status`` on the wire)."""

    #: committed: its table is the current one (pushed, or to be reconciled)
    OK = "ok"
    #: the bundle waits in processing/ for a transient condition to clear
    DEFERRED = "deferred"
    #: the bundle's light is older than the active table's: archived unused
    SUPERSEDED = "superseded"
    #: the input is unusable (a user error): the bundle is rejected
    REJECTED = "rejected"
    #: the run failed (a write, the compute cluster, or a bug)
    FAILED = "failed"
    #: a scheduled run had no input
    SKIPPED = "skipped"
    #: stopped (the daemon is stopping): the bundle is retried at the next start
    INTERRUPTED = "interrupted"


class RunOutcomeJson(TypedDict, total=False):
    """:meth:`RunOutcome.to_json`: ``status`` and the keys that apply, in this order (the
    committed table's from ``table_id`` to ``controllers``; ``controller_crcs`` only where
    known)."""

    status: Required[str]
    run_id: int
    table_id: int | None
    table_crc: int | None
    controller_crcs: dict[str, int]
    metrics: dict[str, Any] | None
    report: str | None
    plot: str | None
    controllers: list[dict[str, str | bool | int | float | None]]
    error: str
    transient: bool
    compute: bool
    retry_in_s: float


@dataclass(frozen=True)
class CommittedTable:
    """What a committed run made: table ``table_id`` with CRC ``table_crc`` (of its uint16
    micrometre table), every controller's own table's CRC (``controller_crcs``; None: not
    known, for a run committed before), its ``metrics``, report and plot paths, and the
    push reports of its controllers (empty: not pushed in this attempt)."""

    table_id: int | None
    table_crc: int | None
    metrics: Mapping[str, Any] | None
    report: str | None
    plot: str | None
    controller_crcs: Mapping[str, int] | None = None
    controllers: tuple[ControllerReport, ...] = ()

    def add_json(self, out: RunOutcomeJson) -> None:
        """Add the keys this part gives :meth:`RunOutcome.to_json` to ``out``."""
        out["table_id"], out["table_crc"] = self.table_id, self.table_crc
        if self.controller_crcs is not None:
            out["controller_crcs"] = dict(self.controller_crcs)
        out["metrics"] = None if self.metrics is None else dict(self.metrics)
        out["report"], out["plot"] = self.report, self.plot
        out["controllers"] = [r.to_json() for r in self.controllers]


@dataclass(frozen=True)
class RunOutcome:
    """A run's (or a bundle attempt's) outcome: ``status``, the run it made (``run_id``,
    None: no run was started), what it committed (``committed``), the ``error`` in words,
    ``transient`` (a failure that may clear: the bundle waits and is tried again),
    ``compute`` (the compute cluster failed, not the input) and ``retry_in_s`` (s until the
    next try of a deferred bundle or waiting run)."""

    status: RunStatus
    run_id: int | None = None
    committed: CommittedTable | None = None
    error: str | None = None
    transient: bool = False
    compute: bool = False
    retry_in_s: float | None = None

    @property
    def ok(self) -> bool:
        """The run committed its table."""
        return self.status is RunStatus.OK

    @property
    def controllers(self) -> tuple[ControllerReport, ...]:
        """The push reports of the run's controllers (empty when none were pushed)."""
        return () if self.committed is None else self.committed.controllers

    def defer(self, reason: str, retry_in_s: float) -> RunOutcome:
        """This outcome for a bundle that now waits in processing/ (``reason``), tried again
        in ``retry_in_s`` seconds."""
        return replace(self, status=RunStatus.DEFERRED, error=reason, retry_in_s=retry_in_s)

    def with_pushes(self, reports: Sequence[ControllerReport]) -> RunOutcome:
        """This committed outcome with the push reports of its controllers."""
        assert self.committed is not None
        return replace(self, committed=replace(self.committed, controllers=tuple(reports)))

    def to_json(self) -> RunOutcomeJson:
        """The wire form: ``status`` and, when they apply, ``run_id``, the committed table's
        keys (:meth:`CommittedTable.add_json`), ``error``, ``transient``, ``compute`` and
        ``retry_in_s``."""
        out: RunOutcomeJson = {"status": self.status.value}
        if self.run_id is not None:
            out["run_id"] = self.run_id
        if self.committed is not None:
            self.committed.add_json(out)
        if self.error is not None:
            out["error"] = self.error
        if self.transient:
            out["transient"] = True
        if self.compute:
            out["compute"] = True
        if self.retry_in_s is not None:
            out["retry_in_s"] = self.retry_in_s
        return out
