"""Retention: keep the state directory from growing for ever (``[retention]`` in the config).

After every run (and at start) :func:`prune` deletes

- bundles in ``archive/`` and ``rejected/`` older than ``keep_days`` (age: when the journal
  archived or rejected them, else the newest mtime of the directory and its ``reason.txt``),
  except the latest archived bundle: scheduled runs take their light from it;
- run reports (``reports/run-NNNNNN.json`` and ``.png``) beyond the newest ``keep_reports``
  runs or older than ``keep_days``, except the active table's report; the history row of a run
  whose report was deleted gets ``report_path``/``plot_path`` NULL, so status never points at a
  missing file;
- history rows beyond the newest ``keep_runs`` runs (with their push rows), except the active
  table's run and unfinished runs, and reconcile push rows older than ``keep_days``;
- ingest journal rows of bundles in a final state (archived or rejected) older than
  ``keep_days`` whose directory is gone from ``archive/`` and ``rejected/`` (removed above, or
  earlier), except the rows of the latest archived bundle and of the active table's bundle;
  rows still ``processing`` (crash recovery needs them) are never touched. A pruned row no
  longer marks its content as seen: a re-upload of that bundle is processed again as new
  rather than rejected as a duplicate, which is acceptable because its light is older than
  ``keep_days`` (the daemon archives it as superseded when newer light made the active
  table); a bundle whose directory could not be removed keeps its row, and so its age;
- leftovers of interrupted atomic writes and cross-device copies (hidden ``*.tmp`` /
  ``*.copy`` entries older than an hour).

After every measurement :func:`prune_measure_photos` deletes the photo folders
(``measure/<id>/``) of all but the newest ``[measure] keep_photos`` measurements; their reports
(``measure/<id>.json``, ``.html``: the trend), the set-up and the correction stay.

Nothing that the daemon needs is ever removed: the active table lives in its history row, and
the light of the next scheduled run in the latest archived bundle.
"""

from __future__ import annotations

import contextlib
import logging
import os
import re
import shutil
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from grassd.daemon.core.config.settings import RetentionConfig
from grassd.daemon.core.store.history import History
from grassd.daemon.core.store.layout import StateLayout, report_run_id

log = logging.getLogger(__name__)

DAY_S = 86400.0
#: Hidden temporaries of interrupted writes older than this (s) are removed.
STALE_TEMP_S = 3600.0


@dataclass
class PruneResult:
    """What one :func:`prune` removed: bundle ids, report files, history runs, ingest journal
    rows, temporaries."""

    bundles: list[str] = field(default_factory=list)
    reports: list[str] = field(default_factory=list)
    runs: int = 0
    temporaries: list[str] = field(default_factory=list)
    journal: int = 0

    def __bool__(self) -> bool:
        return bool(self.bundles or self.reports or self.runs or self.temporaries
                    or self.journal)


def _newest_mtime(d: Path) -> float:
    times = []
    for p in (d, d / "reason.txt"):
        with contextlib.suppress(OSError):
            times.append(p.stat().st_mtime)
    return max(times, default=0.0)


def _remove(p: Path) -> None:
    if p.is_dir() and not p.is_symlink():
        shutil.rmtree(p)
    else:
        p.unlink()


def _prune_reports(reports: Path, history: History, keep_reports: int, active: set[int],
                   cutoff: float, now: float, drop: Callable[[Path, list[str]], None],
                   out: PruneResult) -> None:
    """Drop the report files (``run-NNNNNN.json``/``.png``) of runs beyond the newest
    ``keep_reports`` or older than ``cutoff`` (epoch s), never those of the ``active`` run, and
    stale temporaries; a run whose files are all gone loses its report paths in history."""
    by_run: dict[int, list[Path]] = {}
    for e in reports.iterdir():
        run_id = report_run_id(e.name)
        if run_id is not None:
            by_run.setdefault(run_id, []).append(e)
        elif (e.name.startswith(".") and e.name.endswith(".tmp")
              and _newest_mtime(e) < now - STALE_TEMP_S):
            drop(e, out.temporaries)
    newest = set(sorted(by_run, reverse=True)[:keep_reports])
    for run_id, files in sorted(by_run.items()):
        if run_id in active:
            continue
        if run_id in newest and max(_newest_mtime(f) for f in files) >= cutoff:
            continue
        before = len(out.reports)
        for f in files:
            drop(f, out.reports)
        if len(out.reports) - before == len(files):
            history.update_run(run_id, report_path=None, plot_path=None)


def prune(state_dir: str | os.PathLike[str], history: History, keep: RetentionConfig, *,
          reports_dir: str | os.PathLike[str] | None = None,
          now: float | None = None) -> PruneResult:
    """Apply the retention ``keep`` to ``state_dir`` (archive/, rejected/, reports/) and the
    history database; ``now`` in epoch seconds (default: the clock). Returns what was removed.

    A file that cannot be removed (permissions) is logged and skipped: pruning never fails a
    run.
    """
    layout = StateLayout(state_dir)
    reports = Path(reports_dir) if reports_dir is not None else layout.reports
    now = time.time() if now is None else now
    cutoff = now - keep.keep_days * DAY_S
    out = PruneResult()

    def drop(p: Path, what: list[str]) -> None:
        try:
            _remove(p)
        except OSError as exc:
            log.warning("retention: cannot remove %s: %s", p, exc)
            return
        what.append(p.name)

    # ---- bundles
    finished = {j.bundle_id: j.updated_at for j in history.journal()
                if j.state in ("archived", "rejected")}
    latest = history.latest_archived()
    protected = {latest.bundle_id} if latest is not None else set()
    present: set[str] = set()  # bundle directories left in archive/ and rejected/
    for d in (layout.archive, layout.rejected):
        if not d.is_dir():
            continue
        for e in sorted(d.iterdir()):
            if e.name.startswith("."):
                if e.name.endswith(".copy") and _newest_mtime(e) < now - STALE_TEMP_S:
                    drop(e, out.temporaries)
                continue
            present.add(e.name)
            if e.name in protected:
                continue
            age_at = finished.get(e.name) or _newest_mtime(e)
            if age_at < cutoff:
                drop(e, out.bundles)
    present -= set(out.bundles)

    # ---- ingest journal
    cur = history.current_table()
    keep_rows = {latest.bundle_hash} if latest is not None else set()
    if cur is not None and cur.light_bundle is not None:
        keep_rows.add(cur.light_bundle)
    out.journal = history.prune_journal(cutoff, keep_ids=present, protect=keep_rows)

    # ---- reports
    active = {cur.id} if cur is not None else set()
    if reports.is_dir():
        _prune_reports(reports, history, keep.keep_reports, active, cutoff, now, drop, out)

    # ---- history rows
    out.runs = history.prune_runs(keep.keep_runs, protect=active, reconcile_before=cutoff)
    if out:
        log.info("retention: removed %d bundle(s), %d report file(s), %d history run(s), "
                 "%d ingest journal row(s), %d temporary file(s)", len(out.bundles),
                 len(out.reports), out.runs, out.journal, len(out.temporaries))
    return out


#: A measurement's photo folder: its id, the UTC start ``YYYYmmddTHHMMSSZ``.
_MEASUREMENT_ID = re.compile(r"\d{8}T\d{6}Z")


def prune_measure_photos(measure_dir: str | os.PathLike[str], keep: int) -> list[str]:
    """Delete the photo folders in ``measure_dir`` (``<state>/measure``) of all but the newest
    ``keep`` measurements (by id, their UTC start); returns the ids removed. Anything else
    there (reports, set-up, correction, files not named as a measurement) is left; a folder
    that cannot be removed is logged and skipped."""
    root = Path(measure_dir)
    if not root.is_dir():
        return []
    ids = sorted(e.name for e in root.iterdir()
                 if _MEASUREMENT_ID.fullmatch(e.name) and e.is_dir() and not e.is_symlink())
    removed = []
    for mid in ids[:max(len(ids) - keep, 0)]:
        try:
            shutil.rmtree(root / mid)
        except OSError as exc:
            log.warning("retention: cannot remove the photos of measurement %s: %s", mid, exc)
            continue
        removed.append(mid)
    if removed:
        log.info("retention: removed the photos of %d measurement(s), kept the newest %d",
                 len(removed), keep)
    return removed
