"""The bundle pipeline: one attempt at a claimed bundle, and the bundles that wait.

An attempt archives a bundle already committed (the archive move failed last time), archives
a superseded one unused (its light is older than the light of the active table), resolves the
ambient lux (waiting up to ``light.lux_wait_s`` for a lux sensor outage to end), runs the
calibration and then archives, rejects, releases (an interrupted run is retried at the next
start) or defers the bundle. A deferred bundle waits in processing/ with backoff for a
transient condition (full disk, lux sensor down) to clear.
"""

from __future__ import annotations

import logging
import sqlite3
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from datetime import datetime

from grassd.daemon.core.config.settings import LightConfig
from grassd.daemon.core.errors import DaemonError, LuxSensorSilent, LuxSensorUnreachable
from grassd.daemon.core.runtime.outcome import CommittedTable, RunOutcome, RunStatus
from grassd.daemon.core.safe_text import one_line
from grassd.daemon.core.store.atomic import describe_write_error
from grassd.daemon.core.store.history import History, RunRecord
from grassd.daemon.core.store.ingest import Bundle, Inbox
from grassd.daemon.core.store.manifest import CheckerPhoto
from grassd.daemon.core.timestamps import utc_iso
from grassd.sim.light_input import LightInput

log = logging.getLogger(__name__)


@dataclass
class Deferred:
    """A claimed bundle that waits in processing/ for a transient condition to clear.

    ``retry_at`` and ``give_up_at`` are monotonic seconds (``give_up_at`` None: never);
    ``since`` is epoch seconds (shown in status); ``error``: it waits after an error a pass
    survived (``last_error`` stays until it went through or waits for something else).
    """

    bundle: Bundle
    reason: str
    since: float
    retry_at: float
    delay_s: float
    give_up_at: float | None
    error: bool = False


def light_time(b: Bundle) -> datetime:
    """When bundle ``b``'s light was captured (its manifest timestamp, timezone-aware)."""
    return b.manifest.timestamp


class WaitingBundles:
    """Bundles waiting for a transient failure (full disk, lux sensor down) to clear, by
    bundle hash (``bundles``, read by status from other threads: iterate over a ``list()``
    of it); the first retry after ``retry_s`` seconds, then doubling up to ``retry_max_s``."""

    def __init__(self, history: History, retry_s: float, retry_max_s: float) -> None:
        self.history = history
        self.retry_s = retry_s
        self.retry_max_s = retry_max_s
        self.bundles: dict[str, Deferred] = {}

    def defer(self, b: Bundle, reason: str, limit_s: float | None = None,
              error: bool = False, outcome: RunOutcome | None = None) -> RunOutcome:
        """Leave ``b`` in processing/ (attempt not counted) and retry it with backoff
        (``limit_s``: give up waiting after that many seconds; ``error``: after an error the
        pass survived, see ``last_error``). Returns the attempt's outcome: ``outcome`` (what
        the attempt got so far; None: nothing) made DEFERRED for ``reason``."""
        now = time.monotonic()
        d = self.bundles.get(b.hash)
        if d is None:
            d = Deferred(b, reason, time.time(), now + self.retry_s, self.retry_s,
                         None if limit_s is None else now + limit_s)
            self.bundles[b.hash] = d
        else:
            d.delay_s = min(d.delay_s * 2, self.retry_max_s)
            d.retry_at, d.reason = now + d.delay_s, reason
            if limit_s is not None and d.give_up_at is None:
                d.give_up_at = now + limit_s
        d.error = error
        if limit_s is not None and d.give_up_at is not None and d.give_up_at > now:
            # a wait with a deadline: its last try falls on the deadline, not far beyond; once
            # it has passed, or when it waits for something else (an error), the backoff holds
            d.retry_at = min(d.retry_at, d.give_up_at)
        try:
            self.history.journal_release(b.hash)
        except sqlite3.Error as exc:  # e.g. the disk is full: the attempt stays counted
            log.warning("bundle %s: cannot release its attempt: %s", b.name, exc)
        log.warning("bundle %s waits in processing/: %s; retried in %g s", b.name, reason,
                    d.delay_s)
        return (outcome or RunOutcome(RunStatus.DEFERRED)).defer(reason, d.delay_s)


def superseded(b: Bundle, history: History, inbox: Inbox, future_tolerance_s: float
               ) -> str | None:
    """Why bundle ``b`` must not be applied, or None: its light is older than the light of
    the run whose table is active (:meth:`History.current_table`), whether it was held
    back (waiting for the lux sensor, after a write failure, across a restart) or simply
    uploaded late. Applying it would replace a table made for newer light with one for
    stale conditions.

    Compared by light capture time (manifest timestamps, which the manifest parser
    requires, so every bundle has one). Light exactly as old as the active table's is
    applied: it is a corrected re-upload of the same measurement (identical content is a
    duplicate and never gets here), and the later upload wins. Only a run that made the
    active table counts: a newer run that failed or was rejected made none. The very
    first bundle (no active table) and a bundle arriving while the active table came from
    the embedded default site (no light time) are applied. Where the active run's light
    time was not recorded (a database from before ``light_at``) it is read from that
    run's archived bundle; failing that, only a held-back bundle that arrived before the
    active run's bundle is superseded (by journal claim time). An active light time more
    than ``future_tolerance_s`` seconds in the future outranks nothing. `grassd calibrate
    --now` processes the inbox through here too: the rule holds for it (see
    :meth:`~grassd.daemon.core.runtime.service.Service.one_shot`)."""
    cur = history.current_table()
    if cur is None:
        return None
    active_at = (cur.light_at if cur.light_at is not None
                 else archived_light_at(cur, history, inbox))
    if active_at is not None and active_at > time.time() + future_tolerance_s:
        # stamped in the future, by a daemon from before that was refused at ingest: it
        # outranks nothing, or it would pin the active table until that date
        log.warning("the active table's light (run %d) is stamped in the future (%s); "
                    "bundle %s is not superseded by it", cur.id, utc_iso(active_at), b.name)
        return None
    if active_at is not None:
        ts = b.manifest.timestamp.timestamp()
        if ts >= active_at:
            return None
        iso = [utc_iso(t) for t in (ts, active_at)]
        return (f"superseded: its light ({iso[0]}) is older than the light ({iso[1]}) "
                f"of run {cur.id}, which made the active table {cur.table_id}")
    mine = history.journal_get(b.hash)
    if mine is None or mine.created_at >= cur.started_at:
        return None
    src = cur.light_bundle
    other = None if src is None else history.journal_get(src)
    if other is None or mine.created_at >= other.created_at:
        return None
    return (f"superseded: it arrived before bundle {other.bundle_id}, whose light made "
            f"the active table {cur.table_id} (run {cur.id})")


def archived_light_at(run: RunRecord, history: History, inbox: Inbox) -> float | None:
    """Light capture time (epoch s) of run ``run``'s bundle from its archived manifest,
    for a run recorded without ``light_at``; None when it has no bundle or the bundle is
    gone or unreadable."""
    src = run.light_bundle
    j = None if src is None else history.journal_get(src)
    if j is None or j.state != "archived":
        return None
    try:
        m = inbox.archived_manifest(j.bundle_id)
    except DaemonError:
        return None
    return None if m is None else m.timestamp.timestamp()


#: (run id, light with the ambient lux, checker photo) -> the run's outcome
RunBundle = Callable[[int, LightInput, CheckerPhoto | None], RunOutcome]


def attempt_bundle(b: Bundle, *, history: History, inbox: Inbox, light: LightConfig,
                   waiting: WaitingBundles,
                   lux: Callable[[float | None], tuple[float, str]],
                   begin: Callable[[str], None], run: RunBundle) -> RunOutcome:
    """One attempt at claimed bundle ``b`` (see the module docstring); returns its outcome
    (OK, SUPERSEDED, REJECTED, INTERRUPTED, FAILED or DEFERRED).

    ``lux(manifest_lux)`` gives (lux, source) as
    :func:`~grassd.daemon.core.runtime.ambient_lux.resolve_lux`; ``begin(activity)`` is called
    when the run starts; ``run`` calibrates and commits."""
    mine = history.journal_get(b.hash)
    done = history.ok_run_for_bundle(b.hash, None if mine is None else mine.created_at)
    if done is not None:  # committed, but the archive move failed last time (a run of
        # an earlier upload whose journal row retention pruned does not count)
        inbox.archive_bundle(b, done.id)
        return RunOutcome(RunStatus.OK, done.id, committed=CommittedTable(
            done.table_id, done.table_crc, done.metrics, done.report_path, done.plot_path))
    why = superseded(b, history, inbox, light.future_tolerance_s)
    if why is not None:  # newer light made the active table: do not apply older light
        run_id = history.start_run("bundle", bundle_hash=b.hash,
                                   input_hashes=b.input_hashes,
                                   light_at=b.manifest.timestamp.timestamp())
        history.finish_run(run_id, "superseded", error=why)
        inbox.archive_bundle(b, run_id, reason=why)
        log.warning("bundle %s archived unused: %s", b.name, why)
        return RunOutcome(RunStatus.SUPERSEDED, run_id, error=why)
    inbox.begin(b)
    begin(f"processing bundle {one_line(b.name)}")  # status and sd_notify: the uploader
    # chose the name (a newline, escapes, any length)
    m = b.manifest
    try:
        ambient, source = lux(m.light.ambient_lux)
    except (LuxSensorUnreachable, LuxSensorSilent) as exc:  # an outage: wait for it
        d = waiting.bundles.get(b.hash)
        wait_s = light.lux_wait_s
        if wait_s > 0 and (d is None or d.give_up_at is None
                           or time.monotonic() < d.give_up_at):
            return waiting.defer(b, f"waiting for the lux sensor: {exc}", limit_s=wait_s)
        waited = 0.0 if d is None else time.time() - d.since
        why = (f"no ambient lux: the lux sensor stayed unavailable for {waited:.0f} s "
               f"(light.lux_wait_s = {wait_s:g}): {exc}")
        inbox.reject_bundle(b, why)
        return RunOutcome(RunStatus.REJECTED, error=why)
    except DaemonError as exc:  # a bad reading or no lux source at all: permanent
        inbox.reject_bundle(b, f"no ambient lux: {exc}")
        return RunOutcome(RunStatus.REJECTED, error=str(exc))
    run_id = history.start_run("bundle", bundle_hash=b.hash,
                               input_hashes=b.input_hashes, lux=ambient, lux_source=source,
                               light_at=m.timestamp.timestamp())
    out = run(run_id, replace(m.light, ambient_lux=ambient), m.checker)
    try:
        if out.status is RunStatus.OK:
            inbox.archive_bundle(b, run_id)
        elif out.status is RunStatus.INTERRUPTED:
            history.journal_release(b.hash)  # retried at the next start
        elif out.transient:  # could not write: the bundle is fine, try again later
            return waiting.defer(b, out.error or "", outcome=out)
        else:
            inbox.reject_bundle(b, out.error or "", run_id)
    except OSError as exc:  # e.g. no space for reason.txt: keep the bundle, try again
        return waiting.defer(b, describe_write_error(exc, exc.filename or inbox.state_dir),
                             outcome=out)
    return out
