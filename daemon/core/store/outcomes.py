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

from grassd.daemon.core.store.history import History, JournalEntry

OUTCOMES = ("applied", "superseded", "rejected", "quarantined")
#: the start of the reasons that mark a superseded or quarantined bundle (ingest / service)
SUPERSEDED_PREFIX = "superseded"
QUARANTINED_PREFIX = "abandoned after"


def outcome(state: str, reason: str | None) -> str | None:
    """The outcome (one of :data:`OUTCOMES`) of a bundle whose journal row has ``state`` and
    ``reason``; None while it is processing."""
    reason = reason or ""
    if state == "archived":
        return "superseded" if reason.startswith(SUPERSEDED_PREFIX) else "applied"
    if state == "rejected":
        return "quarantined" if reason.startswith(QUARANTINED_PREFIX) else "rejected"
    return None


def count_outcomes(history: History) -> dict[str, int]:
    """Number of bundles in the journal per outcome (every outcome present, 0 when none);
    one SQL query, so cheap at every reconcile however long the journal."""
    tally = history.journal_tally((SUPERSEDED_PREFIX, QUARANTINED_PREFIX))
    counts = dict.fromkeys(OUTCOMES, 0)
    for (state, prefix), n in tally.items():
        o = outcome(state, prefix)
        if o is not None:
            counts[o] += n
    return counts


def refused(history: History, limit: int = 50) -> list[tuple[str, JournalEntry]]:
    """The newest ``limit`` rejected and quarantined bundles as (outcome, journal row), newest
    first (the journal keeps them as long as ``[retention] keep_days``)."""
    rows = sorted(history.journal("rejected"), key=lambda e: e.updated_at, reverse=True)
    return [(o, e) for e in rows[:limit] if (o := outcome(e.state, e.reason)) is not None]
