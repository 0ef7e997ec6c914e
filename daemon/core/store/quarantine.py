"""Quarantined bundles: list them, and put one back into the inbox to run again.

A bundle whose processing was interrupted ``max_attempts`` times (the daemon crashed, was killed
or lost power while running it) ends in ``rejected/<id>`` as "abandoned" (see
:mod:`grassd.daemon.core.store.ingest`): it may crash the daemon, so it is not retried by itself.
But it may as well have been a valid bundle that met three power cuts; an operator decides.

:func:`quarantined` lists them (for ``grassd status`` and ``grassd bundles list``, from the state
database and the directory). :func:`retry_bundle` puts one back, in steps that are each one
``rename(2)`` or one database transaction, so that a crash at any point loses nothing and
running it again completes it (a bundle left in ``inbox/.retry-<id>`` is listed too):

1. ``rejected/<id>`` -> ``inbox/.retry-<id>`` (hidden: the daemon ignores it);
2. its journal row is deleted, which resets its attempt count (the daemon would otherwise
   reject it as a duplicate of itself), and its ``reason.txt`` removed;
3. ``inbox/.retry-<id>`` -> ``inbox/<name>``: the daemon claims it as a new upload.

It must not run while a daemon's main loop works on the same state directory: the daemon runs
it in its main loop when asked over the control socket (``bundles_retry``); without a daemon,
``grassd bundles retry`` holds the state directory's lock
(:mod:`grassd.daemon.core.runtime.statelock`).
"""

from __future__ import annotations

import logging
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from grassd.daemon.core.errors import DaemonError
from grassd.daemon.core.store.layout import StateLayout
from grassd.daemon.core.store.outcomes import outcome

if TYPE_CHECKING:  # the inbox (and the light it parses) only where a bundle is put back:
    # ``grassd status`` reads the quarantine without it (its start-up stays light)
    from grassd.daemon.core.store.history import History
    from grassd.daemon.core.store.ingest import Inbox

log = logging.getLogger(__name__)

#: Prefix of the hidden name a bundle has in the inbox while it is being put back.
RETRY_PREFIX = ".retry-"


class BundleRetryError(DaemonError):
    """A quarantined bundle cannot be put back (unknown name, a namesake in the inbox...)."""


@dataclass(frozen=True)
class QuarantinedBundle:
    """A bundle in ``rejected/`` that was abandoned after repeated interrupted attempts:
    ``bundle`` its id (directory name), ``name`` its upload name, ``attempts`` how often it was
    started, ``since`` when it was quarantined (epoch s), ``reason`` the journal's reason."""

    bundle: str
    name: str
    attempts: int
    since: float
    reason: str

    def as_dict(self) -> dict[str, object]:
        """The fields as a JSON-ready dict."""
        return asdict(self)


def quarantined(history: History, inbox_dir: Path, state_dir: Path) -> list[QuarantinedBundle]:
    """Bundles abandoned after repeated interrupted attempts whose directory is still in
    ``state_dir/rejected/``, oldest first, then any that a crash left half-way back into
    ``inbox_dir``. Reads only (safe from a status thread, or without a daemon)."""
    out, seen = [], set()
    rejected = StateLayout(state_dir).rejected
    for j in history.journal("rejected"):
        if outcome(j.state, j.reason) != "quarantined":
            continue
        if (rejected / j.bundle_id).is_dir() \
                or (inbox_dir / f"{RETRY_PREFIX}{j.bundle_id}").is_dir():
            out.append(QuarantinedBundle(j.bundle_id, j.name, j.attempts, j.updated_at,
                                         j.reason or ""))
            seen.add(j.bundle_id)
    try:
        staged = sorted(inbox_dir.glob(f"{RETRY_PREFIX}*"))
    except OSError:
        staged = []
    for d in staged:
        bid = d.name[len(RETRY_PREFIX):]
        if d.is_dir() and bid not in seen:
            out.append(QuarantinedBundle(
                bid, bid.split("-", 1)[-1], 0, d.stat().st_mtime,
                f"interrupted while being put back into the inbox: run `grassd bundles retry "
                f"{bid}` again"))
    return out


def _find(inbox: Inbox, bundle: str) -> QuarantinedBundle:
    found = quarantined(inbox.history, inbox.inbox, inbox.state_dir)
    hits = [q for q in found if q.bundle == bundle] or [q for q in found if q.name == bundle]
    if len(hits) == 1:
        return hits[0]
    names = ", ".join(q.bundle for q in found) or "none"
    if not hits:
        raise BundleRetryError(f"no quarantined bundle {bundle!r} (quarantined: {names}); see "
                               "`grassd bundles list`")
    raise BundleRetryError(f"{len(hits)} quarantined bundles are named {bundle!r}: give the "
                           f"id of one ({', '.join(q.bundle for q in hits)})")


def retry_bundle(inbox: Inbox, bundle: str) -> dict[str, object]:
    """Put quarantined ``bundle`` (its id, or its upload name when unique) back into the inbox
    with a fresh attempt count (module docstring); returns what was done (``bundle``, ``name``,
    ``inbox_path``, ``attempts`` before). Raises :class:`BundleRetryError` when there is no such
    bundle or the inbox already holds one of that name."""
    from grassd.daemon.core.store.ingest import REASON_FILE

    q = _find(inbox, bundle)
    target = inbox.inbox / q.name
    if target.exists() or any((inbox.inbox / (q.name + s)).exists()
                              for s in (".manifest.toml", ".manifest.json")):
        raise BundleRetryError(f"the inbox already holds a bundle named {q.name!r} ({target}); "
                               "wait until the daemon has taken it, then retry")
    staged = inbox.inbox / f"{RETRY_PREFIX}{q.bundle}"
    src = inbox.rejected / q.bundle
    if src.is_dir():
        if staged.exists():
            raise BundleRetryError(f"both {src} and {staged} exist: remove the one that is "
                                   "incomplete, then retry")
        inbox._rename(src, staged)  # 1.
    j = next((e for e in inbox.history.journal("rejected") if e.bundle_id == q.bundle), None)
    if j is not None:  # 2.
        inbox.history.journal_forget(j.bundle_hash, state="rejected")
    (staged / REASON_FILE).unlink(missing_ok=True)
    inbox._rename(staged, target)  # 3.
    log.warning("quarantined bundle %s put back into the inbox as %s after %d attempts; it "
                "runs again as a new upload", q.bundle, target, q.attempts)
    return {"bundle": q.bundle, "name": q.name, "inbox_path": str(target),
            "attempts": q.attempts}


@dataclass(frozen=True)
class RetryOutcome:
    """The outcome of putting a quarantined bundle back: ``done``, what
    :func:`retry_bundle` did (None: it failed, ``error`` says why)."""

    done: dict[str, object] | None
    error: str | None = None

    @property
    def ok(self) -> bool:
        """The bundle is back in the inbox."""
        return self.done is not None

    def to_json(self) -> dict[str, object]:
        """The wire form: ``{"status": "ok", ...}`` with what was done, or ``{"status":
        "failed", "error": ...}``."""
        if self.done is not None:
            return {"status": "ok", **self.done}
        return {"status": "failed", "error": self.error}


def retry_request(inbox: Inbox, bundle: str) -> RetryOutcome:
    """:func:`retry_bundle` as a daemon request's result (the main loop must not die of a
    bad name)."""
    try:
        return RetryOutcome(retry_bundle(inbox, bundle))
    except (BundleRetryError, OSError) as exc:
        what = exc if isinstance(exc, BundleRetryError) else f"cannot move it: {exc}"
        return RetryOutcome(None, str(what))
