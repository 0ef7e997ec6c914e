"""The errors a main-loop pass survives (an OSError or SQLite error: a full or read-only disk,
an inbox share that went away): one line each saying what failed, why and the fix, kept for
status as ``last_error`` until a later pass completes without one, and as
``last_error_seen`` (with the time it cleared) after that."""

from __future__ import annotations

import logging
import os
import sqlite3
import time
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path

from grassd.daemon.core.monitoring.status_types import ErrorSeen
from grassd.daemon.core.store.atomic import describe_os_error
from grassd.daemon.core.timestamps import utc_iso

log = logging.getLogger(__name__)


def os_action(exc: BaseException, written: Sequence[Path] = (), otherwise: str = "access"
              ) -> str:
    """What an OSError ``exc`` failed to do, for :func:`describe_os_error`: "write" for a
    rename/link (two paths) or a file below one of the directories ``written``; else
    ``otherwise`` ("read" where only reads remain, "access" where it is not known). An error
    only writes meet (full disk, quota, read-only file system, size limit) is worded as a
    write by :func:`describe_os_error` itself, whatever this says."""
    if not isinstance(exc, OSError):
        return otherwise
    if exc.filename2 is not None:
        return "write"
    if exc.filename is not None:
        p = Path(os.fsdecode(exc.filename))
        if any(p == d or d in p.parents for d in written):
            return "write"
    return otherwise


def describe_error(exc: BaseException, state_dir: Path, db_path: Path,
                   action: str = "access") -> str:
    """One line for an error a main-loop pass survives (what, why, the fix); ``action``:
    what failed on an OSError's file (see :func:`os_action`; ``state_dir`` is named when the
    error has no file); a SQLite error names the state database ``db_path``."""
    if isinstance(exc, OSError):
        return describe_os_error(exc, exc.filename or state_dir, action)
    if isinstance(exc, sqlite3.Error):
        return f"state database {db_path}: {exc}"
    return f"internal error: {exc!r}"


class PassErrors:
    """The errors main-loop passes survived, for status: ``last`` ("<UTC time> <line>") until
    a pass completes without one, ``seen`` (when and what, and when it cleared) after that.
    Status reads both from another thread: ``seen`` is replaced, never changed."""

    def __init__(self) -> None:
        self.last: str | None = None
        self.seen: ErrorSeen | None = None
        #: errors survived in the current pass
        self.in_pass = 0
        #: the last error ended a pass (raised out of the tick)
        self.escaped = False

    def survived(self, msg: str, where: str) -> str:
        """Log error line ``msg`` (at ``where``) and keep it as ``last``; returns ``msg``."""
        at = utc_iso(time.time())
        self.in_pass += 1
        self.escaped = False
        self.seen = ErrorSeen(at=at, error=msg, cleared_at=None)
        self.last = f"{at} {msg}"
        log.error("%s: %s (the daemon keeps running)", where, msg)
        return msg

    def clear(self) -> None:
        """The error of an earlier pass has cleared: ``last`` goes, ``seen`` gets its
        ``cleared_at``."""
        self.last = None
        self.escaped = False
        if self.seen is not None:  # replaced, not changed: status reads it
            self.seen = replace(self.seen, cleared_at=utc_iso(time.time()))
        log.info("the error of an earlier pass has cleared")
