"""The daemon's status as one declared type, :class:`Status`, and its JSON form.

A status is built by :mod:`grassd.daemon.core.runtime.status` (from the state database alone, what
`grassd status` shows without a daemon) and by the running service (with what only the live
process knows, :class:`DaemonState`). It is the control socket's wire format:
:meth:`Status.to_json` on the daemon's side, :meth:`Status.from_json` on the client's
(each JSON object's keys: :mod:`~grassd.daemon.core.monitoring.status_json`).
The metrics, the alerts, the status page and `grassd status` read its attributes.

The JSON keys and their meanings are what ``grassd status --json`` has always printed
(operators' scripts read them): the fields of the database's part, then, only while a daemon
answers (``running`` true), the live fields at the same level. ``health`` is the one-line
verdict of :func:`grassd.daemon.core.monitoring.health.assess`; a :class:`Status` computes it from
its own fields, so every reader of a status sees the same verdict.

Units: times ``*_at`` / ``since`` / ``last_seen`` are epoch seconds (``last_error_seen``'s
are ISO 8601 text), durations ``*_s`` seconds, ``rss_mb`` MiB, CRCs unsigned 32-bit ints.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, TypeGuard

from grassd.daemon.core.monitoring.health import Health, assess
from grassd.daemon.core.monitoring.status_json import (
    ComputeWaitJson,
    ControllerJson,
    DaemonJson,
    DesiredTableJson,
    ErrorSeenJson,
    LiveStatusJson,
    PushRetryJson,
    RunCountsJson,
    RunSummaryJson,
    StatusJson,
    WaitingBundleJson,
)
from grassd.daemon.core.store.quarantine import QuarantinedBundle

__all__ = ["ControllerStatus", "DaemonState", "DesiredTable", "ErrorSeen", "PushRetry",
           "RunCounts", "RunSummary", "Status", "WaitingBundle", "run_r2"]


def run_r2(metrics: Mapping[str, Any]) -> float | None:
    """R^2 of OGCD vs level of a run's metrics: the closed loop's, else the fit's (here, not
    in :mod:`~grassd.daemon.core.monitoring.metrics`: ``grassd status`` needs it without
    prometheus_client)."""
    r2 = metrics.get("r2_closed_loop")
    return metrics.get("r2_after_fit") if r2 is None else r2


def _is_live(d: StatusJson) -> TypeGuard[LiveStatusJson]:
    """Whether a running daemon wrote ``d`` (its live keys are there)."""
    return bool(d.get("running"))


@dataclass(frozen=True)
class DesiredTable:
    """The active table: its ``table_id`` and ``table_crc``, the ``run_id`` that made it, and
    ``per_controller`` (controller name -> CRC of its own table) when the run made one per
    controller (None: one table for every controller)."""

    table_id: int
    table_crc: int
    run_id: int
    per_controller: Mapping[str, int] | None = None

    @classmethod
    def from_json(cls, d: DesiredTableJson) -> DesiredTable:
        """From its JSON form (:meth:`to_json`)."""
        return cls(table_id=d["table_id"], table_crc=d["table_crc"], run_id=d["run_id"],
                   per_controller=d["per_controller"])

    def to_json(self) -> DesiredTableJson:
        """Its JSON form (keys ``table_id``, ``table_crc``, ``run_id``, ``per_controller``)."""
        return {"table_id": self.table_id, "table_crc": self.table_crc, "run_id": self.run_id,
                "per_controller": None if self.per_controller is None
                else dict(self.per_controller)}


@dataclass(frozen=True)
class PushRetry:
    """A controller whose pushes fail (see :mod:`grassd.daemon.core.hardware.fleet`): ``failures``
    in a row, ``since`` (epoch s) the first, backoff ``delay_s``, ``retry_in_s`` until the next
    attempt and the last ``error``."""

    failures: int
    since: float
    delay_s: float
    retry_in_s: float
    error: str | None

    @classmethod
    def from_json(cls, d: PushRetryJson) -> PushRetry:
        """From its JSON form (the keys of the fields)."""
        return cls(failures=d["failures"], since=d["since"], delay_s=d["delay_s"],
                   retry_in_s=d["retry_in_s"], error=d["error"])

    def to_json(self) -> PushRetryJson:
        """Its JSON form (the keys of the fields)."""
        return {"failures": self.failures, "since": self.since, "delay_s": self.delay_s,
                "retry_in_s": self.retry_in_s, "error": self.error}


@dataclass(frozen=True)
class ControllerStatus:
    """One configured controller: ``name`` (``port#address``), what it last reported
    (``table_id``, ``table_crc``, ``last_seen`` epoch s, ``error``), the CRC it should hold
    (``desired_crc``) and whether it does (``in_sync``). ``push_retry``: its push backoff, only
    known to a running daemon (None: its pushes do not fail, or no daemon answered)."""

    name: str
    port: str
    address: int
    reachable: bool
    table_id: int | None
    table_crc: int | None
    desired_crc: int | None
    in_sync: bool
    last_seen: float | None
    error: str | None
    push_retry: PushRetry | None = None

    @property
    def state(self) -> str:
        """``in sync``, ``unreachable`` or ``out of sync``: the word every output uses."""
        if self.in_sync:
            return "in sync"
        return "unreachable" if not self.reachable else "out of sync"

    @classmethod
    def from_json(cls, d: ControllerJson) -> ControllerStatus:
        """From its JSON form (``push_retry`` may be absent)."""
        retry = d.get("push_retry")
        return cls(name=d["name"], port=d["port"], address=d["address"],
                   reachable=d["reachable"], table_id=d["table_id"], table_crc=d["table_crc"],
                   desired_crc=d["desired_crc"], in_sync=d["in_sync"],
                   last_seen=d["last_seen"], error=d["error"],
                   push_retry=None if retry is None else PushRetry.from_json(retry))

    def to_json(self, live: bool) -> ControllerJson:
        """Its JSON form; ``push_retry`` only when ``live`` (a running daemon's status)."""
        d: ControllerJson = {
            "name": self.name, "port": self.port, "address": self.address,
            "reachable": self.reachable, "table_id": self.table_id, "table_crc": self.table_crc,
            "desired_crc": self.desired_crc, "in_sync": self.in_sync,
            "last_seen": self.last_seen, "error": self.error}
        if live:
            d["push_retry"] = None if self.push_retry is None else self.push_retry.to_json()
        return d


@dataclass(frozen=True)
class RunSummary:
    """One run as status lists it: ``id``, ``trigger``, ``status``, ``started_at`` and
    ``finished_at`` (epoch s), ``lux`` and its ``lux_source``, ``error``, ``r2`` (OGCD vs
    level: the closed loop's, else the fit's), ``max_dev_de00`` (dE00) and the ``report`` and
    ``plot`` files."""

    id: int
    trigger: str
    status: str
    started_at: float
    finished_at: float | None
    lux: float | None
    lux_source: str | None
    error: str | None
    r2: float | None
    max_dev_de00: float | None
    report: str | None
    plot: str | None

    @classmethod
    def from_json(cls, d: RunSummaryJson) -> RunSummary:
        """From its JSON form (the keys of the fields)."""
        return cls(id=d["id"], trigger=d["trigger"], status=d["status"],
                   started_at=d["started_at"], finished_at=d["finished_at"], lux=d["lux"],
                   lux_source=d["lux_source"], error=d["error"], r2=d["r2"],
                   max_dev_de00=d["max_dev_de00"], report=d["report"], plot=d["plot"])

    def to_json(self) -> RunSummaryJson:
        """Its JSON form (the keys of the fields)."""
        return {"id": self.id, "trigger": self.trigger, "status": self.status,
                "started_at": self.started_at, "finished_at": self.finished_at,
                "lux": self.lux, "lux_source": self.lux_source, "error": self.error,
                "r2": self.r2, "max_dev_de00": self.max_dev_de00, "report": self.report,
                "plot": self.plot}


@dataclass(frozen=True)
class RunCounts:
    """Runs kept in the history by outcome."""

    ok: int = 0
    rejected: int = 0
    failed: int = 0
    superseded: int = 0

    @classmethod
    def from_json(cls, d: RunCountsJson) -> RunCounts:
        """From its JSON form (the keys of the fields)."""
        return cls(ok=d["ok"], rejected=d["rejected"], failed=d["failed"],
                   superseded=d["superseded"])

    def to_json(self) -> RunCountsJson:
        """Its JSON form (the keys of the fields)."""
        return {"ok": self.ok, "rejected": self.rejected, "failed": self.failed,
                "superseded": self.superseded}


@dataclass(frozen=True)
class WaitingBundle:
    """A bundle waiting in processing/ for a transient failure to clear: ``bundle`` (its
    upload name), ``id`` (directory name), ``reason``, ``since`` (epoch s) and ``retry_in_s``."""

    bundle: str
    id: str
    reason: str
    since: float
    retry_in_s: float

    @classmethod
    def from_json(cls, d: WaitingBundleJson) -> WaitingBundle:
        """From its JSON form (the keys of the fields)."""
        return cls(bundle=d["bundle"], id=d["id"], reason=d["reason"], since=d["since"],
                   retry_in_s=d["retry_in_s"])

    def to_json(self) -> WaitingBundleJson:
        """Its JSON form (the keys of the fields)."""
        return {"bundle": self.bundle, "id": self.id, "reason": self.reason,
                "since": self.since, "retry_in_s": self.retry_in_s}


@dataclass(frozen=True)
class ComputeWait:
    """A run without a bundle (scheduled or requested) that the Dask cluster of ``[compute]
    scheduler`` could not compute, and its automatic retry: ``trigger`` (the run's), ``reason``,
    ``since`` (epoch s of the first failure), ``attempts`` (failed runs in a row) and
    ``retry_in_s``."""

    trigger: str
    reason: str
    since: float
    attempts: int
    retry_in_s: float

    @classmethod
    def from_json(cls, d: ComputeWaitJson) -> ComputeWait:
        """From its JSON form (the keys of the fields)."""
        return cls(trigger=d["trigger"], reason=d["reason"], since=d["since"],
                   attempts=d["attempts"], retry_in_s=d["retry_in_s"])

    def to_json(self) -> ComputeWaitJson:
        """Its JSON form (the keys of the fields)."""
        return {"trigger": self.trigger, "reason": self.reason, "since": self.since,
                "attempts": self.attempts, "retry_in_s": self.retry_in_s}


@dataclass(frozen=True)
class ErrorSeen:
    """The last error a main-loop pass survived: ``at`` (ISO 8601), ``error``, and
    ``cleared_at`` (ISO 8601; None while it lasts)."""

    at: str
    error: str
    cleared_at: str | None

    @classmethod
    def from_json(cls, d: ErrorSeenJson) -> ErrorSeen:
        """From its JSON form (the keys of the fields)."""
        return cls(at=d["at"], error=d["error"], cleared_at=d["cleared_at"])

    def to_json(self) -> ErrorSeenJson:
        """Its JSON form (the keys of the fields)."""
        return {"at": self.at, "error": self.error, "cleared_at": self.cleared_at}


@dataclass(frozen=True)
class DaemonState:
    """What only a running daemon knows: its process (``pid``, ``version``, ``started_at``
    epoch s, ``uptime_s``, ``rss_mb`` MiB), what it does (``activity``), its ``config`` file
    and a refused reload (``reload_error``), the inbox (``inbox``: entries per directory,
    ``inbox_problems``), errors its passes survived (``last_error``, ``last_error_seen``),
    bundles waiting on a transient failure, where its metrics and status page are written,
    the capture station, the serial lines, and a run waiting for compute (``compute_wait``,
    None unless the Dask cluster could not compute the last run without a bundle)."""

    pid: int
    version: str
    activity: str
    started_at: float
    uptime_s: float
    config: str | None
    reload_error: str | None
    #: entries per directory: inbox, processing, archive, rejected
    inbox: Mapping[str, int]
    rss_mb: float
    last_error: str | None
    last_error_seen: ErrorSeen | None
    inbox_problems: tuple[str, ...]
    metrics_textfile: str
    status_page: str
    #: the capture station's own summary (CaptureLoop.summary: camera, interval_s, captures,
    #: last_at, last_success_at, last_bundle, last_error, next_in_s); None without one.
    #: Free-form: its keys are the capture loop's.
    capture: Mapping[str, Any] | None
    #: serial port -> the line's quality snapshot (Fleet.line_quality, read by
    #: grassd.daemon.core.monitoring.line_report); free-form: its keys are the line counters'
    lines: Mapping[str, Mapping[str, Any]]
    waiting_bundles: tuple[WaitingBundle, ...]
    compute_wait: ComputeWait | None = None
    #: what the display shows (ContentStatus.to_json of grassd.daemon.content: source,
    #: frames in and out per second, dropped, latency, receivers); None without [content].
    #: Free-form: its keys are the content feature's.
    content: Mapping[str, Any] | None = None

    @classmethod
    def from_json(cls, d: DaemonJson) -> DaemonState:
        """From a status's JSON form (its live keys; the others are ignored; a daemon from
        before ``compute_wait`` or ``content`` has none)."""
        wait, seen = d.get("compute_wait"), d["last_error_seen"]
        return cls(pid=d["pid"], version=d["version"], activity=d["activity"],
                   started_at=d["started_at"], uptime_s=d["uptime_s"], config=d["config"],
                   reload_error=d["reload_error"], inbox=d["inbox"], rss_mb=d["rss_mb"],
                   last_error=d["last_error"],
                   last_error_seen=None if seen is None else ErrorSeen.from_json(seen),
                   inbox_problems=tuple(d["inbox_problems"]),
                   metrics_textfile=d["metrics_textfile"], status_page=d["status_page"],
                   capture=d["capture"], lines=d["lines"],
                   waiting_bundles=tuple(WaitingBundle.from_json(w)
                                         for w in d["waiting_bundles"]),
                   compute_wait=None if wait is None else ComputeWait.from_json(wait),
                   content=d.get("content"))

    def to_json(self) -> DaemonJson:
        """Its JSON form: the live keys of a status, in this order."""
        return {
            "pid": self.pid, "version": self.version, "activity": self.activity,
            "started_at": self.started_at, "uptime_s": self.uptime_s, "config": self.config,
            "reload_error": self.reload_error, "inbox": dict(self.inbox),
            "rss_mb": self.rss_mb, "last_error": self.last_error,
            "last_error_seen": None if self.last_error_seen is None
            else self.last_error_seen.to_json(),
            "inbox_problems": list(self.inbox_problems),
            "metrics_textfile": self.metrics_textfile, "status_page": self.status_page,
            "capture": None if self.capture is None else dict(self.capture),
            "lines": {port: dict(q) for port, q in self.lines.items()},
            "waiting_bundles": [w.to_json() for w in self.waiting_bundles],
            "compute_wait": None if self.compute_wait is None else self.compute_wait.to_json(),
            "content": None if self.content is None else dict(self.content)}


@dataclass(frozen=True)
class Status:
    """The daemon's status: the active table (``desired_table``, None before the first
    successful run), every controller, the last runs, run counts, quarantined bundles and
    the ``state_dir``; ``daemon``: what the running daemon adds (None: read from the state
    database alone, no daemon answered). ``health`` is computed from these fields
    (:func:`~grassd.daemon.core.monitoring.health.assess`), never given."""

    state_dir: str
    desired_table: DesiredTable | None = None
    controllers: tuple[ControllerStatus, ...] = ()
    runs: tuple[RunSummary, ...] = ()
    run_counts: RunCounts = RunCounts()
    quarantined: tuple[QuarantinedBundle, ...] = ()
    daemon: DaemonState | None = None
    health: Health = field(init=False, compare=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "health", assess(self))

    @property
    def running(self) -> bool:
        """True when a running daemon gave this status."""
        return self.daemon is not None

    def to_json(self) -> StatusJson | LiveStatusJson:
        """The JSON form (``grassd status --json``, the control socket's ``status``): keys
        ``desired_table``, ``controllers``, ``runs``, ``run_counts``, ``quarantined``,
        ``state_dir``, ``running``, ``health``, then, while running, the live keys of
        :class:`DaemonState`."""
        live = self.running
        out: StatusJson = {
            "desired_table": None if self.desired_table is None else self.desired_table.to_json(),
            "controllers": [c.to_json(live) for c in self.controllers],
            "runs": [r.to_json() for r in self.runs],
            "run_counts": self.run_counts.to_json(),
            "quarantined": [{"bundle": q.bundle, "name": q.name, "attempts": q.attempts,
                             "since": q.since, "reason": q.reason} for q in self.quarantined],
            "state_dir": self.state_dir,
            "running": live,
            "health": self.health.summary(),
        }
        if self.daemon is None:
            return out
        both: LiveStatusJson = {**out, **self.daemon.to_json()}
        return both

    @classmethod
    def from_json(cls, d: StatusJson | LiveStatusJson) -> Status:
        """A status from its JSON form (:meth:`to_json`, e.g. the control socket's answer);
        ``health`` is computed again from the fields, by the same function."""
        desired = d["desired_table"]
        return cls(
            state_dir=d["state_dir"],
            desired_table=None if desired is None else DesiredTable.from_json(desired),
            controllers=tuple(ControllerStatus.from_json(c) for c in d["controllers"]),
            runs=tuple(RunSummary.from_json(r) for r in d["runs"]),
            run_counts=RunCounts.from_json(d["run_counts"]),
            quarantined=tuple(QuarantinedBundle(bundle=q["bundle"], name=q["name"],
                                                attempts=q["attempts"], since=q["since"],
                                                reason=q["reason"]) for q in d["quarantined"]),
            daemon=DaemonState.from_json(d) if _is_live(d) else None)
