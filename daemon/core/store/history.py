"""The state database (SQLite, WAL journal): run history, ingest journal, controller state.

Tables:

- ``runs``: one row per calibration run: trigger, bundle hash, input hashes (JSON), lux (lux),
  status (``running``/``ok``/``failed``/``rejected``/``superseded``), error, metrics (JSON),
  the 256-entry length table (JSON list of integer micrometres), its table id and CRC,
  report/plot paths, and ``light_at``: when the light it ran on was captured (epoch s, the
  bundle manifest's timestamp; NULL for the embedded default site). Added to older databases
  by ``ALTER TABLE`` (their old runs have NULL; no schema version change), after the schema
  version check (a database of another version is refused untouched).
- ``pushes``: per-controller push results of each run (and of later reconciles).
- ``run_tables``: the table of every controller of a run whose controllers each have their own
  (``[tables] granularity`` "controller" or "pixel"): controller name, CRC, the table as JSON
  (a list of 256 integer micrometres, or n_pixels such lists). Runs without rows here give
  every controller the run's own table (``runs.lengths_um``). Added to older databases by
  ``CREATE TABLE IF NOT EXISTS`` (no schema version change).
- ``journal``: the ingest journal, one row per bundle keyed by its content hash; state
  ``processing``/``archived``/``rejected`` (see :mod:`grassd.daemon.core.store.ingest`). Rows in a
  final state are pruned with their bundles by retention (:meth:`History.prune_journal`).
- ``controllers``: last reported state of each controller (table id, CRC, reachable, error).

Every write is one transaction; WAL mode lets ``grassd status`` read while the daemon writes.
One :class:`History` may be shared by threads (a lock serialises use of its connection).
"""

from __future__ import annotations

import json
import os
import sqlite3
import threading
import time
from collections.abc import Collection, Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeAlias, TypedDict, Unpack

from grassd.daemon.core.errors import HistoryError

if TYPE_CHECKING:
    import numpy as np

SCHEMA_VERSION = 1

SqlValue: TypeAlias = str | int | float | bytes | None
"""A value SQLite binds to a ``?`` parameter."""


class RunColumns(TypedDict, total=False):
    """The columns of a run that :meth:`History.update_run` may set: lux in lux, lengths in
    um; ``metrics`` is the calibration's metrics object (stored as JSON)."""

    lux: float | None
    lux_source: str | None
    input_hashes: Mapping[str, str]
    metrics: Mapping[str, Any]
    report_path: str | os.PathLike[str] | None
    plot_path: str | os.PathLike[str] | None
    table_id: int | None
    table_crc: int | None
    lengths_um: Sequence[int] | None
    error: str | None

_SCHEMA = """
CREATE TABLE IF NOT EXISTS runs (
    id            INTEGER PRIMARY KEY AUTOINCREMENT,
    started_at    REAL NOT NULL,
    finished_at   REAL,
    trigger       TEXT NOT NULL,
    bundle_hash   TEXT,
    input_hashes  TEXT NOT NULL DEFAULT '{}',
    lux           REAL,
    lux_source    TEXT,
    status        TEXT NOT NULL,
    error         TEXT,
    metrics       TEXT NOT NULL DEFAULT '{}',
    table_id      INTEGER,
    table_crc     INTEGER,
    lengths_um    TEXT,
    report_path   TEXT,
    plot_path     TEXT,
    light_at      REAL
);
CREATE INDEX IF NOT EXISTS runs_bundle ON runs(bundle_hash);
CREATE TABLE IF NOT EXISTS pushes (
    id          INTEGER PRIMARY KEY AUTOINCREMENT,
    run_id      INTEGER REFERENCES runs(id),
    controller  TEXT NOT NULL,
    at          REAL NOT NULL,
    ok          INTEGER NOT NULL,
    table_id    INTEGER,
    table_crc   INTEGER,
    error       TEXT,
    kind        TEXT NOT NULL DEFAULT 'push'
);
CREATE TABLE IF NOT EXISTS journal (
    bundle_hash TEXT PRIMARY KEY,
    bundle_id   TEXT NOT NULL,
    name        TEXT NOT NULL,
    state       TEXT NOT NULL,
    reason      TEXT,
    run_id      INTEGER,
    attempts    INTEGER NOT NULL DEFAULT 0,
    created_at  REAL NOT NULL,
    updated_at  REAL NOT NULL
);
CREATE TABLE IF NOT EXISTS controllers (
    name             TEXT PRIMARY KEY,
    reported_id      INTEGER,
    reported_crc     INTEGER,
    reachable        INTEGER NOT NULL DEFAULT 0,
    last_seen        REAL,
    last_error       TEXT,
    updated_at       REAL NOT NULL
);
CREATE TABLE IF NOT EXISTS run_tables (
    run_id      INTEGER NOT NULL,
    controller  TEXT NOT NULL,
    table_crc   INTEGER NOT NULL,
    lengths_um  TEXT NOT NULL,
    PRIMARY KEY (run_id, controller)
);
CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
"""


@dataclass(frozen=True)
class RunRecord:
    """One row of ``runs``; ``lengths_um`` is the 256-entry table (integer micrometres)."""

    id: int
    started_at: float
    finished_at: float | None
    trigger: str
    bundle_hash: str | None
    input_hashes: dict[str, str]
    lux: float | None
    lux_source: str | None
    status: str
    error: str | None
    metrics: dict[str, Any]
    table_id: int | None
    table_crc: int | None
    lengths_um: tuple[int, ...] | None
    report_path: str | None
    plot_path: str | None
    light_at: float | None = None

    @property
    def light_bundle(self) -> str | None:
        """Hash of the bundle whose light the run used: its own bundle, or for a scheduled
        run the archived bundle it took the light of (``input_hashes["bundle"]``); None for
        the embedded default site."""
        return self.bundle_hash or self.input_hashes.get("bundle")


@dataclass(frozen=True)
class PushRecord:
    """One controller's push (or reconcile) outcome."""

    run_id: int | None
    controller: str
    at: float
    ok: bool
    table_id: int | None
    table_crc: int | None
    error: str | None
    kind: str


@dataclass(frozen=True, eq=False)
class ControllerTable:
    """A controller's own table of a run: ``lengths_um`` (256,) or (n_pixels, 256) uint16
    micrometres and its CRC-32/ISO-HDLC ``table_crc`` (what the controller reports)."""

    run_id: int
    controller: str
    table_crc: int
    lengths_um: np.ndarray


@dataclass(frozen=True)
class JournalEntry:
    """Ingest journal row: ``state`` is processing, archived or rejected."""

    bundle_hash: str
    bundle_id: str
    name: str
    state: str
    reason: str | None
    run_id: int | None
    attempts: int
    created_at: float
    updated_at: float


@dataclass(frozen=True)
class ControllerState:
    """What a controller last reported (table id and CRC) and whether it answered."""

    name: str
    reported_id: int | None
    reported_crc: int | None
    reachable: bool
    last_seen: float | None
    last_error: str | None
    updated_at: float


class History:
    """The SQLite state database at ``path`` (created with its schema when missing)."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._lock = threading.RLock()
        try:
            self._db = sqlite3.connect(self.path, timeout=10.0, isolation_level=None,
                                       check_same_thread=False)
            self._db.execute("PRAGMA journal_mode=WAL")
            self._db.execute("PRAGMA synchronous=FULL")
            self._db.execute("PRAGMA foreign_keys=ON")
            self._check_schema_version()  # before anything is created or altered
            self._db.executescript(_SCHEMA)
            self._add_light_at()
            self._db.execute("INSERT OR IGNORE INTO meta VALUES ('schema', ?)",
                             (str(SCHEMA_VERSION),))
            self._check_schema_version()  # another process may have written it meanwhile
        except HistoryError:
            self._db.close()
            raise
        except sqlite3.DatabaseError as exc:
            raise HistoryError(f"{self.path}: cannot open state database: {exc} "
                               "(is it an SQLite file? is the state directory writable?)") from None

    def _check_schema_version(self) -> None:
        """Raise :class:`HistoryError` when the database records a schema version other than
        :data:`SCHEMA_VERSION` (a database without one, e.g. a new file, passes)."""
        has_meta = self._db.execute("SELECT 1 FROM sqlite_master WHERE type='table' AND "
                                    "name='meta'").fetchone()
        if has_meta is None:
            return
        row = self._db.execute("SELECT value FROM meta WHERE key='schema'").fetchone()
        if row is not None and row[0] != str(SCHEMA_VERSION):
            raise HistoryError(f"{self.path}: schema version {row[0]} is not the supported "
                               f"{SCHEMA_VERSION}; move the old database aside")

    def _add_light_at(self) -> None:
        """Add ``runs.light_at`` to a database from before it. Another process opening the
        same old database may add it between our look and our ``ALTER TABLE``: its
        "duplicate column" error is accepted once the column is seen to exist."""
        def has_it() -> bool:
            return "light_at" in {r[1] for r in self._db.execute("PRAGMA table_info(runs)")}

        if has_it():
            return
        try:
            self._db.execute("ALTER TABLE runs ADD COLUMN light_at REAL")
        except sqlite3.OperationalError as exc:
            if "duplicate column" not in str(exc) or not has_it():
                raise

    # ------------------------------------------------------------------ plumbing
    def close(self) -> None:
        """Close the connection (checkpointing the WAL)."""
        with self._lock:
            self._db.close()

    def __enter__(self) -> History:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    @contextmanager
    def _tx(self) -> Iterator[sqlite3.Connection]:
        with self._lock:
            self._db.execute("BEGIN IMMEDIATE")
            try:
                yield self._db
            except BaseException:
                self._db.execute("ROLLBACK")
                raise
            self._db.execute("COMMIT")

    def _query(self, sql: str, args: Sequence[SqlValue] = ()) -> list[tuple]:
        with self._lock:
            return self._db.execute(sql, args).fetchall()

    def journal_mode(self) -> str:
        """The SQLite journal mode in force (``wal``)."""
        return self._query("PRAGMA journal_mode")[0][0]

    # ------------------------------------------------------------------ runs
    def start_run(self, trigger: str, *, bundle_hash: str | None = None,
                  input_hashes: dict[str, str] | None = None, lux: float | None = None,
                  lux_source: str | None = None, light_at: float | None = None) -> int:
        """Insert a ``running`` row and return its id. ``lux`` in lux; ``light_at``: when its
        light was captured (epoch s, None: not known)."""
        with self._tx() as db:
            cur = db.execute(
                "INSERT INTO runs (started_at, trigger, bundle_hash, input_hashes, lux, lux_source,"
                " status, light_at) VALUES (?, ?, ?, ?, ?, ?, 'running', ?)",
                (time.time(), trigger, bundle_hash, json.dumps(input_hashes or {}, sort_keys=True),
                 lux, lux_source, light_at))
            return int(cur.lastrowid)

    def update_run(self, run_id: int, **fields: Unpack[RunColumns]) -> None:
        """Set some columns of run ``run_id`` (lux, lux_source, input_hashes, metrics, ...)."""
        allowed = {"lux", "lux_source", "input_hashes", "metrics", "report_path", "plot_path",
                   "table_id", "table_crc", "lengths_um", "error"}
        bad = set(fields) - allowed
        if bad:
            raise ValueError(f"cannot update run columns {sorted(bad)}")
        cols: list[str] = []
        vals: list[SqlValue] = []
        for k, v in fields.items():
            if k in ("input_hashes", "metrics"):
                v = json.dumps(v, sort_keys=True, default=_plain)
            elif k == "lengths_um" and v is not None:
                v = json.dumps([int(x) for x in v])
            elif k in ("report_path", "plot_path") and v is not None:
                v = str(v)
            cols.append(f"{k} = ?")
            vals.append(v)
        if not cols:
            return
        with self._tx() as db:
            db.execute(f"UPDATE runs SET {', '.join(cols)} WHERE id = ?", (*vals, run_id))

    def finish_run(self, run_id: int, status: str, **fields: Unpack[RunColumns]) -> None:
        """Close run ``run_id`` with ``status`` (ok, failed, rejected, superseded: a bundle
        whose light is older than the active table's, archived unused) and optional columns."""
        if status not in ("ok", "failed", "rejected", "superseded"):
            raise ValueError(f"bad run status {status!r}")
        if fields:
            fields.setdefault("error", None)
            self.update_run(run_id, **fields)
        with self._tx() as db:
            db.execute("UPDATE runs SET status = ?, finished_at = ? WHERE id = ?",
                       (status, time.time(), run_id))

    def abandon_running(self, reason: str) -> int:
        """Mark runs left ``running`` by a crash or a stop as failed; returns how many."""
        with self._tx() as db:
            cur = db.execute("UPDATE runs SET status='failed', error=?, finished_at=? "
                             "WHERE status='running'", (reason, time.time()))
            return cur.rowcount

    def run(self, run_id: int) -> RunRecord:
        """The run with id ``run_id``."""
        rows = self._query("SELECT * FROM runs WHERE id = ?", (run_id,))
        if not rows:
            raise HistoryError(f"no run with id {run_id}")
        return _run(rows[0])

    def runs(self, limit: int = 20) -> list[RunRecord]:
        """The latest ``limit`` runs, newest first."""
        return [_run(r) for r in self._query("SELECT * FROM runs ORDER BY id DESC LIMIT ?",
                                              (limit,))]

    def run_count(self, status: str | None = None) -> int:
        """Number of runs (with ``status`` when given)."""
        if status is None:
            return self._query("SELECT COUNT(*) FROM runs")[0][0]
        return self._query("SELECT COUNT(*) FROM runs WHERE status = ?", (status,))[0][0]

    def ok_run_for_bundle(self, bundle_hash: str, claimed_at: float | None = None
                          ) -> RunRecord | None:
        """The successful run that consumed bundle ``bundle_hash``, if any. With ``claimed_at``
        (epoch s: when the bundle's journal row was created) only a run started since then: an
        earlier run consumed an earlier upload of the same content whose journal row
        retention has since pruned (:meth:`prune_journal`), so this upload is new."""
        return self._bundle_run(bundle_hash, claimed_at, ok_only=True)

    def last_run_for_bundle(self, bundle_hash: str, claimed_at: float | None = None
                            ) -> RunRecord | None:
        """The latest run (any status) of bundle ``bundle_hash`` started since ``claimed_at``
        (epoch s; see :meth:`ok_run_for_bundle`), if any."""
        return self._bundle_run(bundle_hash, claimed_at, ok_only=False)

    def _bundle_run(self, bundle_hash: str, claimed_at: float | None,
                    ok_only: bool) -> RunRecord | None:
        """The latest run (``ok_only``: the latest ok run) of ``bundle_hash`` started since
        ``claimed_at`` (epoch s; None: any time)."""
        rows = self._query("SELECT * FROM runs WHERE bundle_hash = ? AND started_at >= ? "
                           + ("AND status = 'ok' " if ok_only else "")
                           + "ORDER BY id DESC LIMIT 1",
                           (bundle_hash, -1.0 if claimed_at is None else claimed_at))
        return _run(rows[0]) if rows else None

    def current_table(self) -> RunRecord | None:
        """The latest successful run that produced a table: the table controllers should hold."""
        rows = self._query("SELECT * FROM runs WHERE status = 'ok' AND lengths_um IS NOT NULL "
                           "ORDER BY id DESC LIMIT 1")
        return _run(rows[0]) if rows else None

    def prune_runs(self, keep_last: int, protect: set[int] | frozenset[int] = frozenset(),
                   reconcile_before: float | None = None) -> int:
        """Delete finished runs (and their pushes) older than the newest ``keep_last`` runs,
        except the ids in ``protect`` (e.g. the active table's run); also delete ``reconcile``
        push rows recorded before ``reconcile_before`` (epoch s) of a run that stays.
        Returns the number of runs deleted."""
        keep_last = max(int(keep_last), 1)
        with self._tx() as db:
            ids = [r[0] for r in db.execute(
                "SELECT id FROM runs WHERE status != 'running' AND id NOT IN "
                "(SELECT id FROM runs ORDER BY id DESC LIMIT ?) ORDER BY id", (keep_last,))
                   if r[0] not in protect]
            for chunk, marks in _in_chunks(ids):
                db.execute(f"DELETE FROM pushes WHERE run_id IN ({marks})", chunk)
                db.execute(f"DELETE FROM run_tables WHERE run_id IN ({marks})", chunk)
                db.execute(f"DELETE FROM runs WHERE id IN ({marks})", chunk)
            if reconcile_before is not None:
                db.execute("DELETE FROM pushes WHERE kind = 'reconcile' AND at < ?",
                           (reconcile_before,))
            return len(ids)

    # ------------------------------------------------------------------ per-controller tables
    def record_run_tables(self, run_id: int, tables: Mapping[str, np.ndarray],
                          crcs: Mapping[str, int]) -> None:
        """Store every controller's own table of run ``run_id`` (name -> (256,) or
        (n_pixels, 256) integer micrometres) with its CRC, in one transaction. Call it before
        :meth:`finish_run` marks the run ok, so a current table never lacks them."""
        import numpy as np  # here: ``grassd status`` reads the history without numpy

        rows = [(run_id, name, int(crcs[name]), json.dumps(np.asarray(t, np.int64).tolist()))
                for name, t in tables.items()]
        with self._tx() as db:
            db.executemany("INSERT OR REPLACE INTO run_tables (run_id, controller, table_crc, "
                           "lengths_um) VALUES (?, ?, ?, ?)", rows)

    def run_tables(self, run_id: int) -> dict[str, ControllerTable]:
        """Controller name -> its own table of run ``run_id`` (empty: one table for all)."""
        rows = self._query("SELECT run_id, controller, table_crc, lengths_um FROM run_tables "
                           "WHERE run_id = ? ORDER BY controller", (run_id,))
        if not rows:
            return {}  # without numpy: ``grassd status`` of a display-wide table needs none
        import numpy as np

        return {r[1]: ControllerTable(r[0], r[1], r[2], np.asarray(json.loads(r[3]), np.uint16))
                for r in rows}

    # ------------------------------------------------------------------ pushes / controllers
    def record_push(self, run_id: int | None, controller: str, ok: bool, *,
                    table_id: int | None = None, table_crc: int | None = None,
                    error: str | None = None, kind: str = "push") -> None:
        """Record one controller's push outcome (``kind``: push or reconcile)."""
        with self._tx() as db:
            db.execute("INSERT INTO pushes (run_id, controller, at, ok, table_id, table_crc, "
                       "error, kind) VALUES (?, ?, ?, ?, ?, ?, ?, ?)",
                       (run_id, controller, time.time(), int(ok), table_id, table_crc, error,
                        kind))

    def pushes(self, run_id: int | None = None, limit: int = 100) -> list[PushRecord]:
        """Push records (of run ``run_id`` when given), oldest first."""
        if run_id is None:
            rows = self._query("SELECT * FROM (SELECT * FROM pushes ORDER BY id DESC LIMIT ?) "
                               "ORDER BY id", (limit,))
        else:
            rows = self._query("SELECT * FROM pushes WHERE run_id = ? ORDER BY id", (run_id,))
        return [PushRecord(run_id=r[1], controller=r[2], at=r[3], ok=bool(r[4]), table_id=r[5],
                           table_crc=r[6], error=r[7], kind=r[8]) for r in rows]

    def set_controller(self, name: str, *, reachable: bool, reported_id: int | None = None,
                       reported_crc: int | None = None, error: str | None = None) -> None:
        """Store what controller ``name`` reported (or that it was unreachable)."""
        now = time.time()
        with self._tx() as db:
            if reachable:
                db.execute(
                    "INSERT INTO controllers (name, reported_id, reported_crc, reachable, "
                    "last_seen, last_error, updated_at) VALUES (?, ?, ?, 1, ?, NULL, ?) "
                    "ON CONFLICT(name) DO UPDATE SET reported_id=excluded.reported_id, "
                    "reported_crc=excluded.reported_crc, reachable=1, last_seen=excluded.last_seen,"
                    " last_error=NULL, updated_at=excluded.updated_at",
                    (name, reported_id, reported_crc, now, now))
            else:
                db.execute(
                    "INSERT INTO controllers (name, reachable, last_error, updated_at) "
                    "VALUES (?, 0, ?, ?) ON CONFLICT(name) DO UPDATE SET reachable=0, "
                    "last_error=excluded.last_error, updated_at=excluded.updated_at",
                    (name, error, now))

    def controllers(self) -> list[ControllerState]:
        """Every controller's last known state, by name."""
        return [ControllerState(name=r[0], reported_id=r[1], reported_crc=r[2],
                                reachable=bool(r[3]), last_seen=r[4], last_error=r[5],
                                updated_at=r[6])
                for r in self._query("SELECT * FROM controllers ORDER BY name")]

    # ------------------------------------------------------------------ meta
    def set_meta(self, key: str, value: Any) -> None:
        """Store a small JSON value under ``key`` (e.g. the last colour-correction matrix)."""
        with self._tx() as db:
            db.execute("INSERT INTO meta VALUES (?, ?) ON CONFLICT(key) DO UPDATE SET "
                       "value=excluded.value", (key, json.dumps(value, default=_plain)))

    def get_meta(self, key: str, default: Any = None) -> Any:
        """The JSON value stored under ``key``, or ``default``."""
        rows = self._query("SELECT value FROM meta WHERE key = ?", (key,))
        return json.loads(rows[0][0]) if rows else default

    # ------------------------------------------------------------------ ingest journal
    def journal_claim(self, bundle_hash: str, bundle_id: str, name: str) -> JournalEntry:
        """Insert (or re-open for a retry) the journal row of a bundle entering processing/."""
        now = time.time()
        with self._tx() as db:
            db.execute(
                "INSERT INTO journal (bundle_hash, bundle_id, name, state, attempts, created_at,"
                " updated_at) VALUES (?, ?, ?, 'processing', 0, ?, ?) ON CONFLICT(bundle_hash) "
                "DO UPDATE SET state='processing', updated_at=excluded.updated_at",
                (bundle_hash, bundle_id, name, now, now))
        entry = self.journal_get(bundle_hash)
        assert entry is not None
        return entry

    def journal_attempt(self, bundle_hash: str) -> int:
        """Count one processing attempt of a bundle; returns the attempt number (1 = first)."""
        with self._tx() as db:
            db.execute("UPDATE journal SET attempts = attempts + 1, updated_at = ? "
                       "WHERE bundle_hash = ?", (time.time(), bundle_hash))
            return db.execute("SELECT attempts FROM journal WHERE bundle_hash = ?",
                              (bundle_hash,)).fetchone()[0]

    def journal_release(self, bundle_hash: str) -> None:
        """Undo one attempt count (the attempt was stopped cleanly, not crashed)."""
        with self._tx() as db:
            db.execute("UPDATE journal SET attempts = MAX(attempts - 1, 0) WHERE bundle_hash = ?",
                       (bundle_hash,))

    def journal_finish(self, bundle_hash: str, state: str, *, reason: str | None = None,
                       run_id: int | None = None) -> None:
        """Mark a bundle ``archived`` or ``rejected``."""
        if state not in ("archived", "rejected"):
            raise ValueError(f"bad journal state {state!r}")
        with self._tx() as db:
            db.execute("UPDATE journal SET state=?, reason=?, run_id=COALESCE(?, run_id), "
                       "updated_at=? WHERE bundle_hash=?",
                       (state, reason, run_id, time.time(), bundle_hash))

    def journal_forget(self, bundle_hash: str, state: str = "processing") -> None:
        """Drop a row in ``state`` whose bundle went back to the inbox (``rejected``: a
        quarantined bundle put back by :func:`grassd.daemon.core.store.quarantine.retry_bundle`)."""
        with self._tx() as db:
            db.execute("DELETE FROM journal WHERE bundle_hash=? AND state=?",
                       (bundle_hash, state))

    def journal_get(self, bundle_hash: str) -> JournalEntry | None:
        """The journal row of ``bundle_hash``, if any."""
        rows = self._query("SELECT * FROM journal WHERE bundle_hash = ?", (bundle_hash,))
        return JournalEntry(*rows[0]) if rows else None

    def prune_journal(self, before: float, keep_ids: Collection[str] = (),
                      protect: Collection[str] = ()) -> int:
        """Delete the journal rows of bundles in a final state (``archived``/``rejected``) last
        updated before ``before`` (epoch s), except those whose bundle id is in ``keep_ids``
        (e.g. their directory is still in archive/ or rejected/) or whose hash is in
        ``protect`` (e.g. the latest archived bundle, the active table's bundle). Rows still
        ``processing`` are never deleted. Returns the number of rows deleted.

        A deleted row no longer marks its content as seen: a re-upload of that bundle is not
        rejected as a duplicate but claimed and processed as new (see
        :func:`grassd.daemon.core.runtime.retention.prune`)."""
        keep_ids, protect = set(keep_ids), set(protect)
        with self._tx() as db:
            gone = [h for h, bid in db.execute(
                "SELECT bundle_hash, bundle_id FROM journal WHERE state IN ('archived', "
                "'rejected') AND updated_at < ?", (before,))
                if bid not in keep_ids and h not in protect]
            for chunk, marks in _in_chunks(gone):
                db.execute(f"DELETE FROM journal WHERE state IN ('archived', 'rejected') AND "
                           f"bundle_hash IN ({marks})", chunk)
            return len(gone)

    def journal_count(self, state: str | None = None) -> int:
        """Number of journal rows (in ``state`` when given)."""
        if state is None:
            return self._query("SELECT COUNT(*) FROM journal")[0][0]
        return self._query("SELECT COUNT(*) FROM journal WHERE state = ?", (state,))[0][0]

    def journal_tally(self, prefixes: Sequence[str]) -> dict[tuple[str, str | None], int]:
        """Journal rows counted by state and by which of ``prefixes`` their reason starts with
        (the first that matches; None: none does, or no reason), in one query."""
        args: list[SqlValue] = []
        for prefix in prefixes:
            args += [len(prefix), prefix, prefix]
        case = ("CASE " + " ".join("WHEN substr(reason, 1, ?) = ? THEN ?" for _ in prefixes)
                + " ELSE NULL END") if prefixes else "NULL"
        rows = self._query(f"SELECT state, {case} AS p, COUNT(*) FROM journal "
                           "GROUP BY state, p", args)
        return {(state, p): n for state, p, n in rows}

    def latest_archived(self) -> JournalEntry | None:
        """The most recently archived bundle that a run used (the light of scheduled runs): not
        one archived as superseded (journal reason "superseded: ...")."""
        rows = self._query("SELECT * FROM journal WHERE state = 'archived' AND (reason IS NULL "
                           "OR reason NOT LIKE 'superseded%') ORDER BY updated_at DESC LIMIT 1")
        return JournalEntry(*rows[0]) if rows else None

    def journal(self, state: str | None = None) -> list[JournalEntry]:
        """All journal rows (in ``state`` when given), oldest first."""
        if state is None:
            rows = self._query("SELECT * FROM journal ORDER BY created_at, bundle_id")
        else:
            rows = self._query("SELECT * FROM journal WHERE state = ? ORDER BY created_at, "
                               "bundle_id", (state,))
        return [JournalEntry(*r) for r in rows]


def _plain(obj: Any) -> Any:
    tolist = getattr(obj, "tolist", None)
    if callable(tolist):
        return tolist()
    return str(obj)


def _in_chunks(items: list) -> Iterator[tuple[list, str]]:
    """``items`` in slices of at most 500, each with its "?,?,..." placeholders (an IN list
    within SQLite's bound-parameter limit)."""
    for k in range(0, len(items), 500):
        chunk = items[k:k + 500]
        yield chunk, ",".join("?" * len(chunk))


def _run(r: tuple) -> RunRecord:
    return RunRecord(
        id=r[0], started_at=r[1], finished_at=r[2], trigger=r[3], bundle_hash=r[4],
        input_hashes=json.loads(r[5]), lux=r[6], lux_source=r[7], status=r[8], error=r[9],
        metrics=json.loads(r[10]), table_id=r[11], table_crc=r[12],
        lengths_um=tuple(json.loads(r[13])) if r[13] else None, report_path=r[14],
        plot_path=r[15], light_at=r[16])
