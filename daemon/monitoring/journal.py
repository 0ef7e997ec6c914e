"""Logging for the journal: every line carries its syslog priority, so that
``journalctl -p warning -u grassd`` shows exactly the problems.

:func:`setup_logging` picks the destination:

- under systemd with standard error connected to the journal (``$JOURNAL_STREAM`` names the
  device and inode of our standard error, see systemd.exec(5)), with the ``systemd.journal``
  module (Debian: python3-systemd; PyPI: systemd-python) and journald's native socket:
  journald's native protocol through :class:`systemd.journal.JournalHandler`, with the
  structured fields ``RUN_ID``, ``BUNDLE`` and ``CONTROLLER`` (``journalctl -u grassd
  RUN_ID=12``);
- under systemd without that module or socket: standard error, every line prefixed with ``<N>``, its
  syslog priority (the sd-daemon(3) convention, which journald reads from a service's
  standard error);
- elsewhere (a terminal): standard error with time stamps and level names.

Priorities (syslog(3)): CRITICAL 2 (crit), ERROR 3 (err), WARNING 4 (warning), INFO 6
(info), DEBUG 7 (debug).

The structured fields come from the record: an explicit ``extra={"RUN_ID": 12}`` wins; else
they are read from the message by the project's convention of naming the subject first with
its argument: ``"run %d ..."`` -> RUN_ID, ``"bundle %s ..."`` -> BUNDLE, ``"controller %s ..."``
-> CONTROLLER (:class:`SubjectFields`).
"""

from __future__ import annotations

import logging
import os
import re
import sys
from pathlib import Path
from typing import IO, Any

#: structured journal fields and the word that introduces each in a log message
FIELDS = {"RUN_ID": "run", "BUNDLE": "bundle", "CONTROLLER": "controller"}
_SUBJECT = re.compile(r"\b(run|bundle|controller) (%[sdr])")
_ARG = re.compile(r"%(?:\([^)]*\))?[-#0 +]*(?:\d+|\*)?(?:\.(?:\d+|\*))?[diouxXeEfFgGcrsa%]")
#: journald's socket for its native protocol (where systemd.journal.send writes)
NATIVE_SOCKET = Path("/run/systemd/journal/socket")
TERMINAL_FORMAT = "%(asctime)s %(levelname)s %(name)s: %(message)s"
JOURNAL_FORMAT = "%(name)s: %(message)s"


def syslog_priority(levelno: int) -> int:
    """The syslog priority of logging level ``levelno`` (module docstring).

    >>> [syslog_priority(x) for x in (logging.DEBUG, logging.INFO, logging.WARNING,
    ...                               logging.ERROR, logging.CRITICAL)]
    [7, 6, 4, 3, 2]
    """
    if levelno >= logging.CRITICAL:
        return 2
    if levelno >= logging.ERROR:
        return 3
    if levelno >= logging.WARNING:
        return 4
    if levelno >= logging.INFO:
        return 6
    return 7


class SubjectFields(logging.Filter):
    """Sets ``RUN_ID``, ``BUNDLE`` and ``CONTROLLER`` on a record (module docstring); records
    pass unchanged otherwise."""

    def filter(self, record: logging.LogRecord) -> bool:
        args = record.args if isinstance(record.args, tuple) else ()
        msg = record.msg if isinstance(record.msg, str) else ""
        found: dict[str, Any] = {}
        if args and "%" in msg:
            # argument index of each placeholder by its position ("%%" takes none)
            starts = [m.start() for m in _ARG.finditer(msg) if m.group() != "%%"]
            index = {pos: i for i, pos in enumerate(starts)}
            for m in _SUBJECT.finditer(msg):
                i = index.get(m.start(2))
                if i is not None and i < len(args):
                    found.setdefault(m.group(1), args[i])
        for field, word in FIELDS.items():
            if not hasattr(record, field) and word in found:
                setattr(record, field, str(found[word]))
        return True


class PriorityPrefixFormatter(logging.Formatter):
    """Prefixes every line of a formatted record with ``<N>``, its syslog priority, so that
    journald files a traceback's lines under the record's priority too."""

    def format(self, record: logging.LogRecord) -> str:
        text = super().format(record)
        prefix = f"<{syslog_priority(record.levelno)}>"
        return "\n".join(prefix + line for line in text.split("\n"))


def stderr_is_journal(env: dict[str, str] | None = None, stream: IO[Any] | None = None) -> bool:
    """True when ``stream`` (standard error) is the journal stream systemd connected
    (``$JOURNAL_STREAM`` = "device:inode" of it)."""
    env = os.environ if env is None else env
    stream = sys.stderr if stream is None else stream
    value = env.get("JOURNAL_STREAM", "")
    try:
        dev, ino = (int(x) for x in value.split(":"))
        st = os.fstat(stream.fileno())
    except (ValueError, OSError, AttributeError):
        return False
    return (st.st_dev, st.st_ino) == (dev, ino)


def journal_handler(identifier: str = "grassd", sender: Any = None,
                    socket_path: Path = NATIVE_SOCKET) -> logging.Handler | None:
    """A :class:`systemd.journal.JournalHandler` (native protocol, structured fields; the
    logger's name goes in field LOGGER, so MESSAGE is the message alone), or None when the
    ``systemd.journal`` module is not installed or, with the default ``sender``
    (:func:`systemd.journal.send`, which always writes to :data:`NATIVE_SOCKET`), journald's
    native socket ``socket_path`` is absent."""
    try:
        from systemd.journal import JournalHandler
    except ImportError:
        return None
    if sender is None and not Path(socket_path).is_socket():
        return None
    kw = {} if sender is None else {"sender_function": sender}
    handler = JournalHandler(SYSLOG_IDENTIFIER=identifier, **kw)
    handler.setFormatter(logging.Formatter("%(message)s"))
    return handler


def setup_logging(level: str = "info", *, env: dict[str, str] | None = None,
                  stream: IO[Any] | None = None,
                  native: logging.Handler | None = None) -> logging.Handler | None:
    """Send the root logger's records at ``level`` and above to the journal or standard error
    (module docstring) and return the handler installed. Like :func:`logging.basicConfig`
    it leaves a root logger that already has handlers of others alone (returns None; e.g.
    under pytest); one installed here before is replaced. ``native``: the journal handler to
    use under systemd (default :func:`journal_handler`)."""
    root = logging.getLogger()
    if any(not getattr(h, "_grassd_journal", False) for h in root.handlers):
        return None
    stream = sys.stderr if stream is None else stream
    handler: logging.Handler | None = None
    if stderr_is_journal(env, stream):
        handler = native if native is not None else journal_handler()
        if handler is None:
            handler = logging.StreamHandler(stream)
            handler.setFormatter(PriorityPrefixFormatter(JOURNAL_FORMAT))
    else:
        handler = logging.StreamHandler(stream)
        handler.setFormatter(logging.Formatter(TERMINAL_FORMAT))
    handler.addFilter(SubjectFields())
    handler._grassd_journal = True  # type: ignore[attr-defined]
    for h in list(root.handlers):
        root.removeHandler(h)
    root.addHandler(handler)
    root.setLevel(getattr(logging, level.upper()))
    sys.excepthook = _log_uncaught
    return handler


def _log_uncaught(kind: type[BaseException], exc: BaseException, tb: Any) -> None:
    """An exception that ends the program is logged as CRITICAL (priority 2, with its
    traceback), not written to stderr without a priority."""
    if issubclass(kind, KeyboardInterrupt):
        sys.__excepthook__(kind, exc, tb)
        return
    logging.getLogger("grassd").critical("uncaught exception, the program ends",
                                         exc_info=(kind, exc, tb))
