"""Statuses built by hand for the monitoring and CLI tests: every field given a plain default,
so that a test names only what it is about."""

from __future__ import annotations

from typing import Any

from grassd.daemon.core.monitoring.status_types import (
    ControllerStatus,
    DaemonState,
    DesiredTable,
    RunCounts,
    Status,
    WaitingBundle,
)


def controller(name: str = "bus0#1", *, in_sync: bool = True, reachable: bool = True,
               table_id: int | None = 3, error: str | None = None,
               **kw: Any) -> ControllerStatus:
    """A controller's status (port and address read off ``name``)."""
    port, _, address = name.rpartition("#")
    fields = dict(name=name, port=port or name, address=int(address) if address.isdigit()
                  else 1, reachable=reachable, table_id=table_id, table_crc=None,
                  desired_crc=None, in_sync=in_sync, last_seen=None, error=error)
    return ControllerStatus(**{**fields, **kw})


def waiting(bundle: str, reason: str, retry_in_s: float = 0.0) -> WaitingBundle:
    """A bundle waiting on a transient failure."""
    return WaitingBundle(bundle=bundle, id=f"id-{bundle}", reason=reason, since=0.0,
                         retry_in_s=retry_in_s)


def daemon_state(**kw: Any) -> DaemonState:
    """A running daemon's live state, quiet unless ``kw`` says otherwise."""
    fields = dict(pid=1, version="0", activity="idle", started_at=0.0, uptime_s=0.0,
                  config=None, reload_error=None, inbox={}, rss_mb=0.0, last_error=None,
                  last_error_seen=None, inbox_problems=(), metrics_textfile="",
                  status_page="", capture=None, lines={}, waiting_bundles=())
    return DaemonState(**{**fields, **kw})


def status(*controllers: ControllerStatus, table_id: int | None = 3,
           run_counts: RunCounts | None = None, daemon: DaemonState | None = None,
           **kw: Any) -> Status:
    """A status with ``controllers``, table ``table_id`` active (None: no table yet) and
    one ok run, or ``run_counts``."""
    desired = None if table_id is None else DesiredTable(table_id=table_id, table_crc=1,
                                                        run_id=1)
    counts = run_counts or RunCounts(ok=int(table_id is not None))
    return Status(state_dir="/var/lib/grassd", desired_table=desired,
                  controllers=controllers, run_counts=counts, daemon=daemon, **kw)
