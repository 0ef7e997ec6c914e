"""Wall-clock times as the daemon writes them in logs, alerts, reports and caches: ISO 8601
in UTC to the second (``2026-06-21T12:00:00+00:00``)."""

from __future__ import annotations

from datetime import UTC, datetime


def utc_iso(t: float) -> str:
    """Epoch seconds ``t`` as ISO 8601 UTC to the second, e.g. ``2026-06-21T12:00:00+00:00``."""
    return datetime.fromtimestamp(t, UTC).isoformat(timespec="seconds")
