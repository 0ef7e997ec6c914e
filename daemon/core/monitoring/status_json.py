"""The JSON form of :class:`~grassd.daemon.core.monitoring.status_types.Status` (``grassd
status --json``, the control socket's ``status``): a TypedDict per JSON object, its keys in
the order they are written. Operators' scripts read these keys; each part's reader takes the
keys it knows, so a key a newer daemon adds is left out. Units as in
:mod:`~grassd.daemon.core.monitoring.status_types`.
"""

from __future__ import annotations

from typing import Any, NotRequired, TypedDict


class DesiredTableJson(TypedDict):
    """:class:`~grassd.daemon.core.monitoring.status_types.DesiredTable` as JSON."""

    table_id: int
    table_crc: int
    run_id: int
    per_controller: dict[str, int] | None


class PushRetryJson(TypedDict):
    """:class:`~grassd.daemon.core.monitoring.status_types.PushRetry` as JSON."""

    failures: int
    since: float
    delay_s: float
    retry_in_s: float
    error: str | None


class ControllerJson(TypedDict):
    """:class:`~grassd.daemon.core.monitoring.status_types.ControllerStatus` as JSON
    (``push_retry`` only from a running daemon)."""

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
    push_retry: NotRequired[PushRetryJson | None]


class RunSummaryJson(TypedDict):
    """:class:`~grassd.daemon.core.monitoring.status_types.RunSummary` as JSON."""

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


class RunCountsJson(TypedDict):
    """:class:`~grassd.daemon.core.monitoring.status_types.RunCounts` as JSON."""

    ok: int
    rejected: int
    failed: int
    superseded: int


class QuarantinedJson(TypedDict):
    """A :class:`~grassd.daemon.core.store.quarantine.QuarantinedBundle` as JSON."""

    bundle: str
    name: str
    attempts: int
    since: float
    reason: str


class WaitingBundleJson(TypedDict):
    """:class:`~grassd.daemon.core.monitoring.status_types.WaitingBundle` as JSON."""

    bundle: str
    id: str
    reason: str
    since: float
    retry_in_s: float


class ComputeWaitJson(TypedDict):
    """:class:`~grassd.daemon.core.monitoring.status_types.ComputeWait` as JSON."""

    trigger: str
    reason: str
    since: float
    attempts: int
    retry_in_s: float


class ErrorSeenJson(TypedDict):
    """:class:`~grassd.daemon.core.monitoring.status_types.ErrorSeen` as JSON."""

    at: str
    error: str
    cleared_at: str | None


class DaemonJson(TypedDict):
    """:class:`~grassd.daemon.core.monitoring.status_types.DaemonState` as JSON: the live
    keys of a status (a daemon from before ``compute_wait`` or ``content`` wrote none)."""

    pid: int
    version: str
    activity: str
    started_at: float
    uptime_s: float
    config: str | None
    reload_error: str | None
    inbox: dict[str, int]
    rss_mb: float
    last_error: str | None
    last_error_seen: ErrorSeenJson | None
    inbox_problems: list[str]
    metrics_textfile: str
    status_page: str
    capture: dict[str, Any] | None
    lines: dict[str, dict[str, Any]]
    waiting_bundles: list[WaitingBundleJson]
    compute_wait: NotRequired[ComputeWaitJson | None]
    content: NotRequired[dict[str, Any] | None]


class StatusJson(TypedDict):
    """:class:`~grassd.daemon.core.monitoring.status_types.Status` as JSON, from the state
    database alone (``running`` false)."""

    desired_table: DesiredTableJson | None
    controllers: list[ControllerJson]
    runs: list[RunSummaryJson]
    run_counts: RunCountsJson
    quarantined: list[QuarantinedJson]
    state_dir: str
    running: bool
    health: str


class LiveStatusJson(StatusJson, DaemonJson):
    """:class:`~grassd.daemon.core.monitoring.status_types.Status` as JSON from a running
    daemon (``running`` true): its live keys follow."""
