"""What became of each bundle, from the ingest journal: applied, superseded, rejected or
quarantined.

- ``applied``: archived after a run that made it the active table (journal state archived, no
  reason);
- ``superseded``: archived unused, its light older than the active table's (reason
  "superseded: ...");
- ``quarantined``: rejected because it was attempted ``max_attempts`` times without finishing
  (the daemon stopped or crashed each time: probably a poison bundle; reason "abandoned after
  ..."), see :meth:`grassd.daemon.ingest.Inbox.recover`;
- ``rejected``: every other rejection (bad manifest, bad HDRI, no lux, a run that refused it).

Bundles still in the inbox or in processing/ have no outcome yet (see the queue depths).
"""

from __future__ import annotations

from collections.abc import Iterable

from grassd.daemon.store.history import History, JournalEntry

OUTCOMES = ("applied", "superseded", "rejected", "quarantined")
#: the start of the reasons that mark a superseded or quarantined bundle (ingest / service)
SUPERSEDED_PREFIX = "superseded"
QUARANTINED_PREFIX = "abandoned after"


def outcome(entry: JournalEntry) -> str | None:
    """The outcome of journal row ``entry`` (one of :data:`OUTCOMES`), None while processing."""
    reason = entry.reason or ""
    if entry.state == "archived":
        return "superseded" if reason.startswith(SUPERSEDED_PREFIX) else "applied"
    if entry.state == "rejected":
        return "quarantined" if reason.startswith(QUARANTINED_PREFIX) else "rejected"
    return None


def count_outcomes(entries: Iterable[JournalEntry]) -> dict[str, int]:
    """Number of bundles per outcome (every outcome present, 0 when none)."""
    counts = dict.fromkeys(OUTCOMES, 0)
    for e in entries:
        o = outcome(e)
        if o is not None:
            counts[o] += 1
    return counts


def refused(history: History, limit: int = 50) -> list[tuple[str, JournalEntry]]:
    """The newest ``limit`` rejected and quarantined bundles as (outcome, journal row), newest
    first (the journal keeps them as long as ``[retention] keep_days``)."""
    rows = sorted(history.journal("rejected"), key=lambda e: e.updated_at, reverse=True)
    return [(o, e) for e in rows[:limit] if (o := outcome(e)) is not None]
