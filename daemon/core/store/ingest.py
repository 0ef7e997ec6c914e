"""The inbox: light bundles arrive, are claimed, processed, and end archived or rejected.

A *bundle* is either

- a directory ``inbox/<name>/`` holding ``manifest.toml`` or ``manifest.json`` and the files it
  names, or
- a flat group of files in the inbox: ``<name>.manifest.toml`` (or ``.json``) and the files it
  names, side by side.

The manifest is written last. Hidden names (starting with ``.``) are ignored, so writers may
write ``.partial`` names and rename. Its keys, and the checks that its light can have been,
are :mod:`grassd.daemon.core.store.manifest`'s.

Life of a bundle (all moves are ``rename(2)`` inside the state directory, so each is atomic)::

    inbox/<name> --claim--> processing/<id> --> archive/<id>
                                            \\-> rejected/<id> (+ reason.txt)

``<id>`` = first 12 hex digits of the bundle hash + name. The bundle hash is the SHA-256 over the
names and SHA-256 digests of every file of the bundle, so identical content has one hash.

Crash safety rests on a journal row (SQLite, :class:`~grassd.daemon.core.store.history.History`)
keyed by the bundle hash, written *before* each move: ``processing`` when claimed, ``archived`` /
``rejected`` after the final move. :meth:`Inbox.recover` (run at start) reconciles journal and
directories: a bundle still in ``processing/`` is retried unless a successful run already consumed
it (then it is archived without running again) or it has been attempted ``max_attempts`` times (then
it is rejected: it probably crashes the daemon); a half-moved flat bundle goes back to the inbox; a
bundle whose hash was already archived or rejected is rejected as a duplicate. So no bundle is lost
and none is processed twice.

Duplicates are recognised by the journal row of their hash, and retention
(:func:`grassd.daemon.core.runtime.retention.prune`) deletes the rows of bundles in a final state
once their directories have expired (older than ``[retention] keep_days``), keeping every
``processing`` row and the rows of the latest archived and the active table's bundle. A re-upload of
a bundle whose row was pruned is therefore processed again as new. That is acceptable: its light is
older than ``keep_days``, so unless no newer light made the active table it is archived as
superseded (not applied) by the daemon, and a successful run of the earlier upload is not mistaken
for this upload's (only runs started after its claim count).
"""

from __future__ import annotations

import contextlib
import dataclasses
import errno
import hashlib
import json
import logging
import os
import re
import shutil
import sqlite3
import stat
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from datetime import UTC, tzinfo
from pathlib import Path
from typing import Any, BinaryIO
from zoneinfo import ZoneInfo

from grassd.daemon.core.config.limits import DEFAULT_LIMITS, FUTURE_TOLERANCE_S, BundleLimits
from grassd.daemon.core.config.manifest_fields import plain_name as _plain_name
from grassd.daemon.core.errors import IngestError, ManifestError
from grassd.daemon.core.safe_text import storable
from grassd.daemon.core.store.atomic import atomic_write_text, fsync_dir
from grassd.daemon.core.store.history import History, JournalEntry
from grassd.daemon.core.store.layout import StateLayout
from grassd.daemon.core.store.manifest import (
    MANIFEST_NAMES,
    Manifest,
    check_light,
    load_bundle_manifest,
    parse_manifest,
    read_manifest_text,
)
from grassd.daemon.core.store.outcomes import QUARANTINED_PREFIX
from grassd.daemon.core.store.untrusted import (
    FileIdentity,
    HashedFile,
    UntrustedFileError,
    check_entries,
    check_regular,
    file_identity,
    hash_regular,
    open_regular,
    walk_entries,
)

log = logging.getLogger(__name__)

FLAT_SUFFIXES = (".manifest.toml", ".manifest.json")
REASON_FILE = "reason.txt"
#: Seconds before a bundle that could not be moved out of the inbox is tried again (doubling
#: after each failure up to STUCK_RETRY_MAX_S; at once when its owner or mode changes).
STUCK_RETRY_S = 60.0
STUCK_RETRY_MAX_S = 3600.0
_EXR_MAGIC = b"\x76\x2f\x31\x01"
#: The bytes of a reason.txt read back (the daemon writes one line; a longer one is cut)
MAX_REASON_BYTES = 64 * 1024
_SAFE_RE = re.compile(r"[^A-Za-z0-9._-]+")


@dataclass(frozen=True)
class Bundle:
    """A claimed bundle: its ``dir`` under processing/, content hash and parsed manifest."""

    id: str
    name: str
    hash: str
    dir: Path
    manifest: Manifest
    input_hashes: dict[str, str]


# --------------------------------------------------------------------------- bundle files


def _flat_name(manifest_name: str) -> str:
    """The bundle name of a flat manifest ``NAME.manifest.toml`` (or ``.json``): ``NAME``."""
    return manifest_name[: -len(next(s for s in FLAT_SUFFIXES if manifest_name.endswith(s)))]


def _flat_owner(file_name: str, flat_names: list[str]) -> str | None:
    """The flat bundle that a data file in the inbox belongs to: the longest bundle name N
    (of those whose manifest is there, ``flat_names`` longest first) with the file named
    ``N.<something>``; None when no bundle's name prefixes it."""
    return next((n for n in flat_names if file_name.startswith(n + ".")), None)


def _member(base: Path, key: str, v: Any) -> Path:
    if not _plain_name(v):
        raise ManifestError(f"{key} must be a plain file name inside the bundle, got {v!r}")
    return base / v


def check_open_hdri_header(fh: BinaryIO, name: str) -> None:
    """Reject the HDRI open as ``fh`` (file name ``name``) whose first bytes are not OpenEXR or
    Radiance RGBE as its suffix says, or whose header the renderer cannot take
    (:func:`grassd.sim.hdri.read_open_header`: more than
    :data:`~grassd.sim.hdri.RENDERER_TEXELS` texels, several parts, other channels)."""
    from grassd.sim.errors import HdriError
    from grassd.sim.hdri import RENDERER_TEXELS, read_open_header

    try:
        fh.seek(0)
        head = fh.read(16)
    except OSError as exc:
        raise IngestError(f"cannot read HDRI {name}: {exc.strerror}") from None
    suffix = Path(name).suffix.lower()
    if suffix == ".exr" and head[:4] != _EXR_MAGIC:
        raise IngestError(f"HDRI {name} is not an OpenEXR file (bad magic number)")
    if suffix == ".hdr" and not head.startswith((b"#?RADIANCE", b"#?RGBE")):
        raise IngestError(f"HDRI {name} is not a Radiance .hdr file (no #?RADIANCE header)")
    try:
        read_open_header(fh, name, RENDERER_TEXELS)
    except HdriError as exc:
        raise IngestError(f"HDRI {exc}") from None


def bundle_hash(input_hashes: dict[str, str]) -> str:
    """Content hash of a bundle from its ``{file name: sha256}`` map (manifest included)."""
    return hashlib.sha256(json.dumps(sorted(input_hashes.items())).encode()).hexdigest()


# --------------------------------------------------------------------------- the inbox


@dataclass(frozen=True)
class _ScannedManifest:
    """A manifest as a scan read it: the stat ``key`` it was read under (device, inode,
    modification and change times, size, mode), the data, the parsed manifest or the error,
    and the SHA-256 of the bytes read (the bundle's hash of it while ``key`` holds)."""

    key: tuple
    data: dict[str, Any] | None
    parsed: Manifest | None
    error: str | None
    sha256: str | None


@dataclass
class _Claimed:
    """What a claim read of a bundle's files, each opened once: ``hashes`` (``{name in the
    bundle: SHA-256}``), the files' identities when hashed, the manifest's data when its hash
    is of those bytes, and the HDRI's header check (None: passed; else why it failed; not
    checked when ``hdri_checked`` is False)."""

    hashes: dict[str, str] = dataclasses.field(default_factory=dict)
    identities: dict[str, FileIdentity] = dataclasses.field(default_factory=dict)
    manifest_data: dict[str, Any] | None = None
    hdri_checked: bool = False
    hdri_error: str | None = None


def _stat_key(st: os.stat_result) -> tuple:
    """The key a scanned manifest is kept under (:class:`_ScannedManifest`)."""
    return (st.st_dev, st.st_ino, st.st_mtime_ns, st.st_ctime_ns, st.st_size, st.st_mode)


@dataclass
class _Stuck:
    """A bundle whose move out of the inbox failed: why, when to retry (clock s), and the
    owners/modes seen then (:meth:`Inbox._access_key`)."""

    message: str
    retry_at: float
    delay_s: float
    access: tuple


@dataclass
class _Candidate:
    name: str                      # as the journal and messages show it (storable)
    manifest: Path | None          # None: directory bundle without manifest (yet)
    members: list[Path]            # everything that moves with the bundle (manifest last)
    parsed: Manifest | None
    parse_error: str | None
    missing: list[str]
    #: (path, lstat) of every entry of the members (a directory's walked without following
    #: links, at most the entries cap + 1): the settle signature and the caps' input
    entries: list[tuple[Path, os.stat_result]] = dataclasses.field(default_factory=list)
    #: the name as the file system has it (``name`` escapes bytes that are not UTF-8): the
    #: key of the inbox's watch and backoff, and what files are matched and moved back by
    raw: str = ""
    #: the manifest as the scan read it (None: none read)
    scanned: _ScannedManifest | None = None

    @property
    def key(self) -> str:
        """The name on disk (:attr:`raw`, else :attr:`name`)."""
        return self.raw or self.name


class Inbox:
    """Watches ``inbox`` and moves bundles through ``state_dir``/{processing,archive,rejected}.

    ``settle_s``: files must keep size and mtime this long before a bundle is claimed;
    ``incomplete_timeout_s``: a bundle still missing files after this long is rejected.
    ``future_tolerance_s`` and ``site`` (latitude, longitude in degrees): see
    :func:`~grassd.daemon.core.store.manifest.check_light`, which every manifest passes before its
    bundle is claimed.
    ``limits``: the caps on a bundle (:class:`~grassd.daemon.core.config.limits.BundleLimits`);
    whatever arrives is read as hostile (:mod:`grassd.daemon.core.store.untrusted`), and a manifest
    is parsed once per (inode, mtime, size), not on every scan.
    ``clock`` (seconds, monotonic) and ``wall_clock`` (epoch seconds, the daemon's own clock
    that light timestamps are checked against) are injectable for tests.
    """

    def __init__(self, inbox: Path, state_dir: Path, history: History, *,
                 settle_s: float = 2.0, incomplete_timeout_s: float = 600.0,
                 tz: tzinfo | str = UTC, max_attempts: int = 3,
                 future_tolerance_s: float = FUTURE_TOLERANCE_S,
                 site: tuple[float, float] | None = None,
                 limits: BundleLimits = DEFAULT_LIMITS,
                 clock: Callable[[], float] = time.monotonic,
                 wall_clock: Callable[[], float] = time.time) -> None:
        self.inbox = Path(inbox)
        self.state_dir = Path(state_dir)
        layout = StateLayout(self.state_dir)
        self.processing, self.archive, self.rejected = (layout.processing, layout.archive,
                                                         layout.rejected)
        for d in (self.inbox, self.processing, self.archive, self.rejected):
            d.mkdir(parents=True, exist_ok=True)
        self.history = history
        self.settle_s = settle_s
        self.incomplete_timeout_s = incomplete_timeout_s
        self.tz = ZoneInfo(tz) if isinstance(tz, str) else tz
        self.max_attempts = max_attempts
        self.future_tolerance_s = future_tolerance_s
        self.site = site
        self.limits = limits
        self.clock = clock
        self.wall_clock = wall_clock
        self._watch: dict[str, tuple[tuple, float, float]] = {}  # name -> (sig, since, first)
        self._stuck: dict[str, _Stuck] = {}  # bundles whose move out of the inbox failed
        #: manifest path -> the manifest as last read there
        self._parsed: dict[Path, _ScannedManifest] = {}

    # ------------------------------------------------------------------ scanning
    def _candidates(self) -> list[_Candidate]:
        out: list[_Candidate] = []
        try:
            entries = sorted(os.scandir(self.inbox), key=lambda e: e.name)
        except FileNotFoundError:
            if self.inbox.is_symlink():  # a link to a share that went away: nothing to create
                raise
            self.inbox.mkdir(parents=True, exist_ok=True)
            return out
        flat = sorted((_flat_name(e.name) for e in entries if e.name.endswith(FLAT_SUFFIXES)
                       and not e.name.startswith(".")), key=len, reverse=True)
        for e in entries:
            if e.name.startswith("."):
                continue
            try:
                if e.is_dir(follow_symlinks=False):
                    base = Path(e.path)
                    found = [base / m for m in MANIFEST_NAMES if os.path.lexists(base / m)]
                    if len(found) > 1:
                        out.append(_Candidate(storable(e.name), found[0], [base], None,
                                              "bundle has both manifest.toml and "
                                              "manifest.json", [], raw=e.name))
                        continue
                    out.append(self._examine(e.name, found[0] if found else None, base,
                                             [base]))
                elif e.name.endswith(FLAT_SUFFIXES):
                    out.append(self._examine(_flat_name(e.name), Path(e.path), self.inbox,
                                             None, flat))
            except (OSError, sqlite3.Error):
                raise
            except Exception as exc:  # noqa: BLE001 - hostile input must not stop the scan
                log.exception("inbox: examining %r failed", e.name)
                out.append(_Candidate(storable(e.name), None, [Path(e.path)], None,
                                      f"could not be examined: {type(exc).__name__}: {exc}", [],
                                      raw=e.name))
        for gone in set(self._parsed) - {c.manifest for c in out}:
            del self._parsed[gone]
        return out

    def _read_manifest(self, manifest: Path, base: Path) -> _ScannedManifest:
        """``manifest`` read and parsed once per stat key (:class:`_ScannedManifest`), so a
        large manifest waiting for its files costs one parse, not one per scan, and the claim
        hashes the bytes read here."""
        try:
            key = _stat_key(manifest.lstat())
        except OSError:
            key = ()
        cached = self._parsed.get(manifest)
        if cached is not None and key and cached.key == key:
            return cached
        data: dict[str, Any] | None = None
        parsed, err, digest = None, None, None
        try:
            text, data = read_manifest_text(manifest, self.limits.manifest_bytes)
            digest = hashlib.sha256(text.encode("utf-8")).hexdigest()
            parsed = parse_manifest(data, base, self.tz)
        except ManifestError as exc:
            err = str(exc)
        scanned = _ScannedManifest(key, data, parsed, err, digest)
        self._parsed[manifest] = scanned
        return scanned

    def _examine(self, raw: str, manifest: Path | None, base: Path,
                 members: list[Path] | None, flat: list[str] = ()) -> _Candidate:
        """The candidate bundle ``raw`` (its name on disk) with ``manifest`` (None: none yet)
        in ``base``; ``members``: what moves with it (None: a flat bundle's, found from its
        manifest; ``flat``: the flat bundles' names on disk, longest first)."""
        name = storable(raw)
        if manifest is None:
            c = _Candidate(name, None, members or [], None, None, ["manifest.toml"], raw=raw)
            c.entries = walk_entries(c.members, self.limits.entries)
            return c
        missing = []
        scanned = self._read_manifest(manifest, base)
        data, parsed, err = scanned.data, scanned.parsed, scanned.error
        if parsed is not None:
            try:
                check_light(parsed, now=self.wall_clock(),
                            future_tolerance_s=self.future_tolerance_s, site=self.site)
            except ManifestError as exc:
                err = str(exc)
        named = [] if parsed is None else parsed.files()
        if members is None:  # flat bundle: data files first, manifest last
            if parsed is None:  # rejected manifest: still take along the data files it names
                named = [_member(base, k, data[k]) for k in ("hdri", "checker_raw")
                         if data is not None and _plain_name(data.get(k))
                         and not data[k].startswith(".") and not data[k].endswith(FLAT_SUFFIXES)]
            stolen = [p.name for p in named if _flat_owner(p.name, flat) != raw]
            if stolen:  # another flat bundle's file (or nobody's): never move it
                named = [p for p in named if p.name not in stolen]
                err = err or (f"names {', '.join(stolen)}, which a flat bundle {name} may not: "
                              f"its files must be named {name}.<something> (and not belong to "
                              "a longer bundle name)")
            members = [*(p for p in named if os.path.lexists(p)), manifest]
        for p in named:
            try:
                st = p.lstat()
            except FileNotFoundError:
                missing.append(p.name)
                continue
            except OSError as exc:
                err = err or f"cannot examine {p.name}: {exc.strerror}"
                continue
            try:
                check_regular(st, p.name, self.limits.file_bytes)
            except UntrustedFileError as exc:
                err = err or str(exc)
        c = _Candidate(name, manifest, members, parsed, err, missing, raw=raw, scanned=scanned)
        c.entries = walk_entries(members, self.limits.entries)
        if c.parse_error is None:
            try:
                check_entries(c.entries, manifest.parent, self.limits)
            except UntrustedFileError as exc:
                c.parse_error = str(exc)
        return c

    @staticmethod
    def _signature(c: _Candidate) -> tuple:
        return tuple((str(p), st.st_mode, st.st_size, st.st_mtime_ns) for p, st in c.entries)

    # ------------------------------------------------------------------ public API
    def poll(self, claim: bool = True) -> list[Bundle]:
        """Scan the inbox once: claim complete, settled bundles into processing/ and return them.

        Bundles with an invalid manifest, or still incomplete after the timeout, are claimed and
        rejected at once (with their reason); duplicates of already-handled bundles likewise.
        ``claim=False`` only watches (tracks sizes and mtimes for the settle time), so bundles
        are settled by the time a later poll may claim them.

        When claiming one bundle fails (OSError, SQLite error: e.g. rejected/ unwritable, a
        full disk) after others were claimed, those are returned (they are in processing/
        already and would otherwise wait there until the next restart) and the error is
        logged; with none claimed, it is raised.
        """
        ready: list[Bundle] = []
        try:
            self._scan(claim, ready)
        except (OSError, sqlite3.Error) as exc:
            if not ready:
                raise
            log.error("inbox: claiming a bundle failed (%s); the %d bundle(s) claimed before it "
                      "go ahead", exc, len(ready))
        return ready

    def _scan(self, claim: bool, ready: list[Bundle]) -> None:
        """:meth:`poll`'s scan: claimed bundles are appended to ``ready`` as they are moved."""
        now = self.clock()
        names = set()
        for c in self._candidates():
            names.add(c.key)
            try:
                self._consider(c, now, claim, ready)
            except (OSError, sqlite3.Error):
                raise
            except Exception as exc:  # noqa: BLE001 - one hostile bundle must not stop the
                # daemon (a parser's RecursionError, a name no file system takes, ...)
                log.exception("inbox: bundle %r could not be handled", c.name)
                self._watch.pop(c.key, None)
                try:
                    self._claim_and_reject(c, f"could not be handled: {type(exc).__name__}: "
                                              f"{exc}")
                except Exception as again:  # noqa: BLE001 - left in the inbox, tried later
                    prev = self._stuck.get(c.key)
                    delay = STUCK_RETRY_S if prev is None else min(prev.delay_s * 2,
                                                                   STUCK_RETRY_MAX_S)
                    msg = (f"bundle {c.name} can be neither processed nor rejected "
                           f"({type(again).__name__}: {again}); remove it from the inbox")
                    self._stuck[c.key] = _Stuck(msg, now + delay, delay, self._access_key(c))
                    log.error("%s (tried again in %g s)", msg, delay)
        for gone in set(self._watch) - names:
            del self._watch[gone]
        for gone in set(self._stuck) - names:
            del self._stuck[gone]

    def _consider(self, c: _Candidate, now: float, claim: bool, ready: list[Bundle]) -> None:
        """:meth:`_scan` for one candidate: watch it settle, then claim or reject it."""
        stuck = self._stuck.get(c.key)
        if stuck is not None and now < stuck.retry_at \
                and stuck.access == self._access_key(c):
            return
        sig = self._signature(c)
        prev = self._watch.get(c.key)
        if prev is None or prev[0] != sig:
            first = prev[2] if prev else now
            self._watch[c.key] = (sig, now, first)
            if self.settle_s > 0:
                return
            prev = self._watch[c.key]
        if not claim:
            return
        _, since, first = prev
        settled = now - since >= self.settle_s
        if (c.missing or c.manifest is None) and c.parse_error is None:
            if now - first >= self.incomplete_timeout_s and settled:
                what = ("no manifest.toml or manifest.json" if c.manifest is None
                        else f"missing file(s) {', '.join(c.missing)}")
                self._claim_and_reject(c, f"incomplete bundle after "
                                          f"{self.incomplete_timeout_s:g} s: {what}")
                self._watch.pop(c.key, None)
            return
        if not settled:
            return
        self._watch.pop(c.key, None)
        if c.parse_error is not None:
            self._claim_and_reject(c, c.parse_error)
            return
        bundle = self._claim(c)
        if bundle is not None:
            ready.append(bundle)

    def problems(self) -> list[str]:
        """Why bundles wait in the inbox (e.g. permissions), one line each, for status (called
        from a control-socket thread: reads a snapshot of what the main loop changes)."""
        stuck = dict(self._stuck)
        return [stuck[name].message for name in sorted(stuck)]

    def recover(self) -> list[Bundle]:
        """Reconcile journal and directories after a crash; return bundles to process again.

        Each bundle is recovered on its own: one that cannot be (an error of any kind) is
        quarantined in rejected/ with the error as its reason, or, when even that fails, left
        where it is and logged, so no bundle can keep the daemon from starting."""
        retry: list[Bundle] = []
        rows = {j.bundle_id: j for j in self.history.journal("processing")}
        # 1. flat bundles interrupted half-way into processing/: put them back.
        for d in sorted(self.processing.glob("*.partial")):
            bid = d.name[: -len(".partial")]
            row = rows.pop(bid, None)
            with self._recovering(d, row):
                name = row.name if row else bid.split("-", 1)[-1]
                self._unclaim_partial(d, name)
                if row:
                    self.history.journal_forget(row.bundle_hash)
        # 2. journal rows still "processing".
        for bid, row in rows.items():
            with self._recovering(self.processing / bid, row):
                self._recover_row(bid, row, retry)
        # 3. directories in processing/ that the journal does not know (database replaced).
        known = {j.bundle_id for j in self.history.journal()}
        for d in sorted(self.processing.iterdir()):
            if d.is_dir() and not d.is_symlink() and not d.name.endswith(".partial") \
                    and d.name not in known:
                with self._recovering(d, None):
                    self._recover_unknown(d, retry)
        return retry

    @contextlib.contextmanager
    def _recovering(self, d: Path, row: JournalEntry | None) -> Iterator[None]:
        """Recover bundle directory ``d`` (journal ``row`` or None) on its own (:meth:`recover`)."""
        try:
            yield
        except sqlite3.Error:
            raise  # the journal itself: not one bundle's fault
        except Exception as exc:  # noqa: BLE001 - quarantine the one bundle, go on
            log.exception("recovering bundle %s failed", d.name)
            reason = (f"{QUARANTINED_PREFIX} could not be recovered after a restart: "
                      f"{type(exc).__name__}: {exc}")
            try:
                if d.is_dir() and not d.is_symlink():
                    self._finish_dir(d, d.name.removesuffix(".partial"),
                                     None if row is None else row.bundle_hash, reason)
                elif row is not None:
                    self.history.journal_finish(row.bundle_hash, "rejected", reason=reason)
            except Exception:  # noqa: BLE001 - e.g. a full disk: left for the next start
                log.exception("bundle %s could not be quarantined either; it stays in %s",
                              d.name, d.parent)

    def _recover_row(self, bid: str, row: JournalEntry, retry: list[Bundle]) -> None:
        """:meth:`recover` step 2 for one journal row still ``processing``."""
        here = self.processing / bid
        if here.is_dir():
            b = self._retry_or_settle(row.bundle_hash, bid, row.name, row.attempts)
            if b is not None:
                retry.append(b)
        elif (self.archive / bid).is_dir():  # crashed between move and journal: a
            # superseded bundle stays superseded (scheduled runs must not take its light)
            run = self.history.last_run_for_bundle(row.bundle_hash, row.created_at)
            self.history.journal_finish(
                row.bundle_hash, "archived", run_id=None if run is None else run.id,
                reason=run.error if run is not None and run.status == "superseded" else None)
        elif (self.rejected / bid).is_dir():
            self.history.journal_finish(row.bundle_hash, "rejected",
                                        reason=self._read_reason(self.rejected / bid))
        elif (self.inbox / row.name).exists() or any(
                (self.inbox / (row.name + s)).exists() for s in FLAT_SUFFIXES):
            self.history.journal_forget(row.bundle_hash)  # crashed before the move
        else:
            log.error("bundle %s vanished from processing/ while the daemon was down", bid)
            self.history.journal_finish(row.bundle_hash, "rejected",
                                        reason="bundle files vanished after a crash")

    def _recover_unknown(self, d: Path, retry: list[Bundle]) -> None:
        """:meth:`recover` step 3 for one directory the journal does not know."""
        name = d.name.split("-", 1)[-1]
        try:
            hashes = self._hash_dir(d).hashes
        except (OSError, IngestError) as exc:
            self._finish_dir(d, d.name, None, f"unreadable after a crash: {exc}")
            return
        h = bundle_hash(hashes)
        done = self.history.journal_get(h)
        if done is not None:  # its content is known under another id: a duplicate
            # caught mid-rejection by a crash; the original keeps its journal row
            self._finish_dir(d, d.name, None, f"duplicate: identical content was "
                                              f"already {done.state} as {done.bundle_id}")
            return
        self.history.journal_claim(h, d.name, name)
        b = self._retry_or_settle(h, d.name, name, 0)
        if b is not None:
            retry.append(b)

    def begin(self, bundle: Bundle) -> int:
        """Count one processing attempt of ``bundle`` (call right before processing it)."""
        return self.history.journal_attempt(bundle.hash)

    def archive_bundle(self, bundle: Bundle, run_id: int | None,
                       reason: str | None = None) -> Path:
        """Move a processed bundle to archive/ and mark it archived (``reason``: why it was
        archived without being applied, e.g. superseded)."""
        dest = self.archive / bundle.id
        self._rename(bundle.dir, dest)
        self.history.journal_finish(bundle.hash, "archived", run_id=run_id, reason=reason)
        return dest

    def reject_bundle(self, bundle: Bundle, reason: str, run_id: int | None = None) -> Path:
        """Move a bundle to rejected/ with ``reason`` written to reason.txt; mark it rejected."""
        return self._finish_dir(bundle.dir, bundle.id, bundle.hash, reason, run_id)

    def archived_manifest(self, bundle_id: str) -> Manifest | None:
        """The parsed manifest of archived bundle ``bundle_id`` (naive times in the site's
        zone), or None when its directory or manifest is gone; ManifestError (a DaemonError)
        when it cannot be read."""
        return load_bundle_manifest(self.archive / bundle_id, self.tz,
                                    self.limits.manifest_bytes)

    def counts(self) -> dict[str, int]:
        """Number of entries in inbox, processing, archive and rejected."""
        def n(d: Path) -> int:
            return sum(1 for e in d.iterdir() if not e.name.startswith(".")) if d.is_dir() else 0
        return {"inbox": n(self.inbox), "processing": n(self.processing),
                "archive": n(self.archive), "rejected": n(self.rejected)}

    # ------------------------------------------------------------------ internals
    def _retry_or_settle(self, h: str, bid: str, name: str, attempts: int) -> Bundle | None:
        d = self.processing / bid
        row = self.history.journal_get(h)
        done = self.history.ok_run_for_bundle(h, None if row is None else row.created_at)
        if done is not None:  # processed, crashed before the archive move: do not run again
            self._rename(d, self.archive / bid)
            self.history.journal_finish(h, "archived", run_id=done.id)
            return None
        if attempts >= self.max_attempts:
            self._finish_dir(d, bid, h, f"{QUARANTINED_PREFIX} {attempts} attempts that did not "
                                        "finish (the daemon stopped or crashed each time); "
                                        f"`grassd bundles retry {bid}` runs it again")
            return None
        try:
            return self._load_claimed(d, bid, name, h)
        except (IngestError, OSError) as exc:
            self._finish_dir(d, bid, h, str(exc))
            return None

    def _load_claimed(self, d: Path, bid: str, name: str, h: str | None,
                      claimed: _Claimed | None = None) -> Bundle:
        """The claimed bundle in ``d``. ``claimed``: what the claim read before the move; its
        manifest data and hashes are used where every file is still the one hashed (else,
        and without it, each file is read again here)."""
        if claimed is not None and claimed.manifest_data is not None:
            manifest: Manifest | None = parse_manifest(claimed.manifest_data, d, self.tz)
        else:
            claimed = None
            manifest = load_bundle_manifest(d, self.tz, self.limits.manifest_bytes)
        if manifest is None:
            raise IngestError("bundle has no manifest.toml or manifest.json")
        missing = [p.name for p in manifest.files() if not os.path.lexists(p)]
        if missing:
            raise IngestError(f"missing file(s) {', '.join(missing)}")
        entries = self._checked_entries(d)  # every entry a regular file within the caps
        if claimed is None or not self._unchanged(d, entries, claimed):
            claimed = self._hash_dir(d, entries, manifest.light.hdri)
        if claimed.hdri_error is not None:
            raise IngestError(claimed.hdri_error)
        return Bundle(id=bid, name=name, hash=h or bundle_hash(claimed.hashes), dir=d,
                      manifest=manifest, input_hashes=claimed.hashes)

    def _checked_entries(self, d: Path) -> list[tuple[Path, os.stat_result]]:
        """(path, lstat) of every regular file below ``d`` but the daemon's reason.txt, after
        :func:`check_entries` (UntrustedFileError: an entry not a regular file, a cap broken)."""
        entries = walk_entries([d], self.limits.entries)
        check_entries([(p, st) for p, st in entries if p != d / REASON_FILE], d, self.limits)
        return sorted(((p, st) for p, st in entries
                       if stat.S_ISREG(st.st_mode) and p != d / REASON_FILE),
                      key=lambda e: e[0])

    @staticmethod
    def _unchanged(d: Path, entries: list[tuple[Path, os.stat_result]],
                   claimed: _Claimed) -> bool:
        """Whether the files below ``d`` are exactly those ``claimed`` hashed, unchanged."""
        now = {str(p.relative_to(d)): file_identity(st) for p, st in entries}
        return now == claimed.identities and claimed.hdri_checked

    def _hash_file(self, p: Path, key: str, out: _Claimed, hdri: Path | None,
                   known: dict[Path, HashedFile]) -> None:
        """Hash ``p`` into ``out`` under ``key`` (``known``: files hashed already); the HDRI's
        header is checked from the same open file (its failure kept in ``out``, raised once
        the bundle is claimed)."""
        def header(fh: BinaryIO) -> None:
            try:
                check_open_hdri_header(fh, p.name)
            except IngestError as exc:
                out.hdri_error = str(exc)
            out.hdri_checked = True

        f = known.get(p) or hash_regular(p, self.limits.file_bytes,
                                         header if p == hdri else None)
        out.hashes[key], out.identities[key] = f.sha256, f.identity

    def _hash_dir(self, d: Path, entries: list[tuple[Path, os.stat_result]] | None = None,
                  hdri: Path | None = None, out: _Claimed | None = None,
                  known: dict[Path, HashedFile] | None = None) -> _Claimed:
        """Every file below ``d`` but the daemon's reason.txt hashed into ``out`` (keys
        relative to ``d``; ``entries``: :meth:`_checked_entries` of ``d``, made here when
        None), the header of ``hdri`` checked from its open file."""
        out = _Claimed() if out is None else out
        for p, _ in self._checked_entries(d) if entries is None else entries:
            self._hash_file(p, str(p.relative_to(d)), out, hdri, known or {})
        return out

    def _hash_members(self, c: _Candidate) -> _Claimed:
        """The candidate's files, each opened and hashed once: the manifest's hash is the
        scan's while its stat key holds (its data, then, is what the claim keeps)."""
        out = _Claimed()
        hdri = None if c.parsed is None else c.parsed.light.hdri
        known: dict[Path, HashedFile] = {}
        if self._scan_holds(c):
            assert c.manifest is not None and c.scanned is not None
            assert c.scanned.sha256 is not None
            known[c.manifest] = HashedFile(c.scanned.sha256, file_identity(c.manifest.lstat()))
            out.manifest_data = c.scanned.data
        for m in c.members:
            if m.is_dir() and not m.is_symlink():
                self._hash_dir(m, None, hdri, out, known)
            else:
                key = ("manifest" + m.name[m.name.rfind(".") :]) if m == c.manifest else m.name
                self._hash_file(m, key, out, hdri, known)
        return out

    @staticmethod
    def _scan_holds(c: _Candidate) -> bool:
        """Whether the candidate's manifest is still the file its scan read and parsed."""
        s = c.scanned
        if c.manifest is None or s is None or s.sha256 is None or s.parsed is None:
            return False
        try:
            return _stat_key(c.manifest.lstat()) == s.key
        except OSError:
            return False

    def _bundle_id(self, h: str, name: str) -> str:
        return f"{h[:12]}-{_SAFE_RE.sub('_', name)[:80]}"

    def _claim(self, c: _Candidate) -> Bundle | None:
        try:
            claimed = self._hash_members(c)
        except UntrustedFileError as exc:  # changed into something the daemon will not read
            self._claim_and_reject(c, str(exc))
            return None
        except OSError as exc:  # a file vanished between scan and claim: look again next time
            log.warning("bundle %s changed while being claimed: %s", c.name, exc)
            return None
        h = bundle_hash(claimed.hashes)
        bid = self._bundle_id(h, c.name)
        existing = self.history.journal_get(h)
        if existing is not None:
            dup = f"{bid}.dup-{time.time_ns()}"
            d = self._try_move_in(c, dup, None)
            if d is None:
                return None
            self._write_reason(d, f"duplicate: identical content was already {existing.state} "
                                  f"as {existing.bundle_id}")
            self._rename(d, self.rejected / dup)
            return None
        self.history.journal_claim(h, bid, c.name)
        d = self._try_move_in(c, bid, h)
        if d is None:
            return None
        try:
            return self._load_claimed(d, bid, c.name, h, claimed)
        except (IngestError, OSError) as exc:
            self._finish_dir(d, bid, h, str(exc))
            return None

    def _claim_and_reject(self, c: _Candidate, reason: str) -> None:
        try:
            hashes = self._hash_members(c).hashes
        except (OSError, IngestError):  # e.g. a FIFO: the entries' kinds and sizes then
            hashes = {"name": hashlib.sha256(c.name.encode()).hexdigest(),
                      "entries": hashlib.sha256(repr(self._signature(c)).encode()).hexdigest()}
        h = bundle_hash(hashes)
        bid = self._bundle_id(h, c.name)
        if self.history.journal_get(h) is not None:
            bid = f"{bid}.dup-{time.time_ns()}"
            d = self._try_move_in(c, bid, None)
            if d is not None:
                self._finish_dir(d, bid, None, reason)
            return
        self.history.journal_claim(h, bid, c.name)
        d = self._try_move_in(c, bid, h)
        if d is not None:
            self._finish_dir(d, bid, h, reason)

    def _access_key(self, c: _Candidate) -> tuple:
        """Owner, group and mode of the inbox and of the bundle's top-level entries: when one
        changes (someone fixed the permissions) a stuck bundle is tried again at once."""
        key = []
        for p in [self.inbox, *c.members]:
            try:
                st = p.lstat()
            except OSError:
                continue
            key.append((str(p), st.st_uid, st.st_gid, st.st_mode))
        return tuple(key)

    def _try_move_in(self, c: _Candidate, bid: str, h: str | None) -> Path | None:
        """:meth:`_move_in`, or None when the bundle cannot be moved out of the inbox: it is
        left there as it was, its fresh journal row ``h`` dropped, and tried again after
        STUCK_RETRY_S (doubling) or as soon as an owner or mode changes; the reason and the
        fix are logged once and listed by :meth:`problems`."""
        try:
            dest = self._move_in(c, bid)
        except OSError as exc:
            if h is not None:
                self.history.journal_forget(h)
            prev = self._stuck.get(c.key)
            delay = STUCK_RETRY_S if prev is None else min(prev.delay_s * 2, STUCK_RETRY_MAX_S)
            msg = self._move_error(c, exc)
            self._stuck[c.key] = _Stuck(msg, self.clock() + delay, delay, self._access_key(c))
            if prev is None or prev.message != msg:
                log.error("%s (it stays in the inbox; tried again when its owner or mode "
                          "changes, else in %g s)", msg, delay)
            else:
                log.debug("bundle %s still cannot be moved; next try in %g s", c.name, delay)
            return None
        if self._stuck.pop(c.key, None) is not None:
            log.info("bundle %s could be moved out of the inbox now", c.name)
        return dest

    def _move_error(self, c: _Candidate, exc: OSError) -> str:
        """One line: which bundle could not be moved, why, and what fixes it."""
        head = f"cannot move bundle {c.name} out of the inbox {self.inbox}: {exc.strerror or exc}"
        fix = f"chgrp grassd {self.inbox}; chmod 2775 {self.inbox}"
        if exc.errno not in (errno.EACCES, errno.EPERM):
            return head + " (give the daemon write access to the inbox and the bundle)"
        me = os.geteuid()
        try:
            inbox_st = self.inbox.stat()
        except OSError:
            return head
        if inbox_st.st_mode & stat.S_ISVTX and inbox_st.st_uid != me:
            return (head + f": the inbox has the sticky bit (mode {inbox_st.st_mode & 0o7777:o})"
                    ", so only an entry's owner may move it: chmod -t it, make it group-writable"
                    f" and setgid ({fix})")
        for m in c.members:
            try:
                st = m.lstat()
            except OSError:
                continue
            if m.is_dir() and st.st_uid != me and not st.st_mode & stat.S_IWGRP:
                return (head + f": bundle directory {m.name} belongs to uid {st.st_uid} with mode "
                        f"{st.st_mode & 0o7777:o} (written with umask 022), and moving a "
                        "directory needs write access to it: make the inbox group-writable and "
                        f"setgid ({fix}) and have the uploader use "
                        "umask 002, or upload flat bundles (NAME.manifest.toml beside its files)")
            if m.is_dir() and not os.access(m, os.W_OK):
                return (head + f": bundle directory {m.name} (uid {st.st_uid}, mode "
                        f"{st.st_mode & 0o7777:o}) is not writable by the daemon (uid {me}), "
                        "and moving a directory needs write access to it: make it group-"
                        f"writable (uploader umask 002) in a setgid, group-writable inbox ({fix})")
        return (head + f": the daemon (uid {me}) needs write access to the inbox (mode "
                f"{inbox_st.st_mode & 0o7777:o}, uid {inbox_st.st_uid}, gid {inbox_st.st_gid}): "
                f"make it group-writable and setgid ({fix})")

    def _move_in(self, c: _Candidate, bid: str) -> Path:
        dest = self.processing / bid
        if len(c.members) == 1 and c.members[0].is_dir():
            self._rename(c.members[0], dest)
            return dest
        partial = self.processing / f"{bid}.partial"
        partial.mkdir(exist_ok=True)
        try:
            for m in c.members:  # manifest is last
                target = m.name
                if m == c.manifest:
                    target = "manifest" + m.name[m.name.rfind(".") :]
                if os.path.lexists(m):
                    self._rename(m, partial / target)
            self._rename(partial, dest)
        except OSError:
            with contextlib.suppress(OSError):  # else recover() puts them back at the next start
                self._unclaim_partial(partial, c.key)
            raise
        return dest

    def _unclaim_partial(self, d: Path, name: str) -> None:
        files = sorted(d.iterdir())
        manifests = [f for f in files if f.name in MANIFEST_NAMES]
        for f in [f for f in files if f not in manifests] + manifests:
            target = name + "." + f.name if f in manifests else f.name
            self._rename(f, self.inbox / target)
        d.rmdir()
        log.warning("bundle %s was half-way into processing/: moved back to the inbox", name)

    def _finish_dir(self, d: Path, bid: str, h: str | None, reason: str,
                    run_id: int | None = None) -> Path:
        reason = storable(reason)  # it may quote names that are not UTF-8
        self._write_reason(d, reason)
        dest = self.rejected / bid
        self._rename(d, dest)
        if h is not None:
            self.history.journal_finish(h, "rejected", reason=reason, run_id=run_id)
        log.warning("rejected bundle %s: %s", bid, reason)
        return dest

    @staticmethod
    def _write_reason(d: Path, reason: str) -> None:
        """Write ``reason`` to ``d``/reason.txt; an uploaded reason.txt that is not a regular
        file (a directory, a FIFO: a rename could not replace it, or a reader would block) is
        first moved aside to ``uploaded-reason.txt-<ns>``."""
        target = d / REASON_FILE
        with contextlib.suppress(FileNotFoundError):
            if not stat.S_ISREG(target.lstat().st_mode):
                os.rename(target, d / f"uploaded-{REASON_FILE}-{time.time_ns()}")
        atomic_write_text(target, reason.rstrip() + "\n")

    @staticmethod
    def _read_reason(d: Path) -> str | None:
        """The reason.txt of bundle directory ``d`` (None when unreadable or not a regular
        file; cut at MAX_REASON_BYTES)."""
        try:
            fd = open_regular(d / REASON_FILE, 1 << 62)
            try:
                raw = os.read(fd, MAX_REASON_BYTES)
            finally:
                os.close(fd)
        except (OSError, IngestError):
            return None
        return raw.decode("utf-8", errors="replace").strip()

    @staticmethod
    def _rename(src: Path, dst: Path) -> None:
        """rename(2) ``src`` to ``dst`` (fsyncing both parents); across file systems, copy the
        tree to a hidden temporary beside ``dst``, fsync, rename it, then remove ``src``."""
        try:
            os.rename(src, dst)
        except OSError as exc:
            if exc.errno != errno.EXDEV:
                raise
            tmp = dst.parent / f".{dst.name}.copy"
            if src.is_dir() and not src.is_symlink():  # links copied as links, never followed
                shutil.copytree(src, tmp, symlinks=True, dirs_exist_ok=True,
                                copy_function=_copy_regular)
            else:
                _copy_regular(src, tmp)
            for p in [tmp, *tmp.rglob("*")] if tmp.is_dir() else [tmp]:
                if stat.S_ISREG(p.lstat().st_mode):  # a link was copied as a link: skipped
                    fd = os.open(p, os.O_RDONLY | os.O_NOFOLLOW)
                    try:
                        os.fsync(fd)
                    finally:
                        os.close(fd)
            os.rename(tmp, dst)
            if src.is_dir():
                shutil.rmtree(src)
            else:
                src.unlink()
        fsync_dir(dst.parent)
        if src.parent != dst.parent:
            fsync_dir(src.parent)


def _copy_regular(src: str | os.PathLike[str], dst: str | os.PathLike[str]) -> None:
    """shutil.copy2 for a regular file or a link (copied as the link); anything else (a FIFO,
    a device: reading it could block or never end) becomes an empty file of the same name."""
    if stat.S_ISREG(os.lstat(src).st_mode) or os.path.islink(src):
        shutil.copy2(src, dst, follow_symlinks=False)
    else:
        Path(dst).touch()
