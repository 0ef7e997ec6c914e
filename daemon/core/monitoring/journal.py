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

One record is one line: a message may carry a name chosen by whoever writes the
inbox, and a newline in it would print a forged second line (under systemd one with a
priority prefix of its choosing). Every formatter here writes the message through
:func:`~grassd.daemon.core.safe_text.one_line` (``\\n``, ``\\x1b`` ... instead of the raw
characters), as the structured fields too; only a traceback keeps its lines (each prefixed
with the record's priority), with the exception's own text made one line. Logging never
stops the daemon: a handler that fails reports it once on standard error and goes on.
"""

from __future__ import annotations

import logging
import os
import re
import sys
import traceback
from pathlib import Path
from types import TracebackType
from typing import Protocol, TextIO, TypeAlias

from grassd.daemon.core.safe_text import one_line

#: structured journal fields and the word that introduces each in a log message
FIELDS = {"RUN_ID": "run", "BUNDLE": "bundle", "CONTROLLER": "controller"}
_SUBJECT = re.compile(r"\b(run|bundle|controller) (%[sdr])")
_ARG = re.compile(r"%(?:\([^)]*\))?[-#0 +]*(?:\d+|\*)?(?:\.(?:\d+|\*))?[diouxXeEfFgGcrsa%]")
#: journald's socket for its native protocol (where systemd.journal.send writes)
NATIVE_SOCKET = Path("/run/systemd/journal/socket")
TERMINAL_FORMAT = "%(asctime)s %(levelname)s %(name)s: %(message)s"
#: what ``sys.exc_info()`` gives (and :meth:`logging.Formatter.formatException` takes)
ExcInfo: TypeAlias = (tuple[type[BaseException], BaseException, TracebackType | None]
                      | tuple[None, None, None])


class JournalSender(Protocol):
    """What sends a record to the journal for :class:`systemd.journal.JournalHandler`
    (``sender_function``; :func:`systemd.journal.send`): the message and its fields, each
    written as text."""

    def __call__(self, MESSAGE: str, **fields: object) -> object:  # noqa: N803 (the field)
        ...
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
    """Sets ``RUN_ID``, ``BUNDLE`` and ``CONTROLLER`` on a record (module docstring), each
    made one line (:func:`~grassd.daemon.core.safe_text.one_line`); records pass unchanged
    otherwise. Never raises (a record it cannot read gets no fields)."""

    def filter(self, record: logging.LogRecord) -> bool:
        try:
            self._fields(record)
        except Exception:  # a filter runs outside the handler's error handling
            pass
        return True

    @staticmethod
    def _fields(record: logging.LogRecord) -> None:
        args = record.args if isinstance(record.args, tuple) else ()
        msg = record.msg if isinstance(record.msg, str) else ""
        found: dict[str, object] = {}  # a logging call's arguments may be anything
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
                setattr(record, field, one_line(found[word]))


def _exception_only_lines(te: traceback.TracebackException) -> set[str]:
    """What :meth:`~traceback.TracebackException.format` writes for the exceptions
    themselves ("Type: message", notes) along ``te``'s chain, as opposed to frames."""
    out: set[str] = set()
    seen: set[int] = set()
    todo = [te]
    while todo:
        t = todo.pop()
        if id(t) in seen:
            continue
        seen.add(id(t))
        out.update(t.format_exception_only())
        todo.extend(x for x in (t.__cause__, t.__context__) if x is not None)
        todo.extend(getattr(t, "exceptions", None) or ())
    return out


class OneLineFormatter(logging.Formatter):
    """A :class:`logging.Formatter` whose message is always one line (module docstring):
    control characters of the message, after ``%`` interpolation, become visible escapes.
    A traceback keeps its lines, but an exception's text in it (which may quote a name) is
    made one line, and no line carries a control character."""

    def formatMessage(self, record: logging.LogRecord) -> str:  # noqa: N802 (logging's name)
        """The format applied to the record with its message made one line."""
        message = record.message
        record.message = one_line(message, None)
        try:
            return super().formatMessage(record)
        finally:
            record.message = message

    def formatException(self, ei: ExcInfo) -> str:  # noqa: N802 (logging's name)
        """The traceback of ``ei`` (``sys.exc_info()``): one text line per line of the
        traceback."""
        if ei[1] is None:  # logged with exc_info outside an exception handler
            return _lines_safe(super().formatException(ei))
        te = traceback.TracebackException(*ei)
        own = _exception_only_lines(te)
        parts = [one_line(p.removesuffix("\n"), None) + "\n" if p in own else p
                 for p in te.format()]
        return _lines_safe("".join(parts).removesuffix("\n"))

    def formatStack(self, stack_info: str) -> str:  # noqa: N802 (logging's name)
        """A stack as Python wrote it, each line without control characters."""
        return _lines_safe(stack_info)


def _lines_safe(text: str) -> str:
    """``text`` with its line breaks kept and every line made one line."""
    return "\n".join(one_line(line, None) for line in text.split("\n"))


class PriorityPrefixFormatter(OneLineFormatter):
    """Prefixes every line of a formatted record with ``<N>``, its syslog priority, so that
    journald files a traceback's lines under the record's priority too. The message itself
    is one line (:class:`OneLineFormatter`), so no text in it starts a line of its own."""

    def format(self, record: logging.LogRecord) -> str:
        """The record's lines, each prefixed with ``<N>``."""
        text = super().format(record)
        prefix = f"<{syslog_priority(record.levelno)}>"
        return "\n".join(prefix + line for line in text.split("\n"))


class _ReportOnce:
    """A handler's ``handleError``: the first failure of each kind is reported on standard
    error in one line (with the priority prefix, for journald), later ones are dropped;
    never raises."""

    def __init__(self, handler: logging.Handler) -> None:
        self.handler = handler
        self.seen: set[str] = set()

    def __call__(self, record: logging.LogRecord) -> None:
        try:
            exc = sys.exc_info()[1]
            kind = type(exc).__name__
            if kind in self.seen:
                return
            self.seen.add(kind)
            sys.stderr.write(f"<4>grassd: logging through {type(self.handler).__name__} "
                             f"failed: {one_line(f'{kind}: {exc}', 500)} (the daemon goes on; "
                             "further failures of this kind are not reported)\n")
            sys.stderr.flush()
        except Exception:
            pass


def _never_raise(handler: logging.Handler) -> logging.Handler:
    """Make ``handler`` never raise into the code that logs: its errors (a formatter's, a
    failed write or send, even RecursionError, which :class:`logging.StreamHandler` passes
    on) go to a once-per-kind report (:class:`_ReportOnce`)."""
    report = _ReportOnce(handler)
    emit = handler.emit

    def safe_emit(record: logging.LogRecord) -> None:
        try:
            emit(record)
        except Exception:
            report(record)

    handler.emit = safe_emit  # type: ignore[method-assign]
    handler.handleError = report  # type: ignore[method-assign]
    return handler


def stderr_is_journal(env: dict[str, str] | None = None, stream: TextIO | None = None) -> bool:
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


def journal_handler(identifier: str = "grassd", sender: JournalSender | None = None,
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
    handler.setFormatter(OneLineFormatter("%(message)s"))
    return handler


def setup_logging(level: str = "info", *, env: dict[str, str] | None = None,
                  stream: TextIO | None = None,
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
        handler.setFormatter(OneLineFormatter(TERMINAL_FORMAT))
    handler.addFilter(SubjectFields())
    _never_raise(handler)
    handler._grassd_journal = True  # type: ignore[attr-defined]
    for h in list(root.handlers):
        root.removeHandler(h)
    root.addHandler(handler)
    root.setLevel(getattr(logging, level.upper()))
    sys.excepthook = _log_uncaught
    return handler


def _log_uncaught(kind: type[BaseException], exc: BaseException, tb: TracebackType | None
                  ) -> None:
    """An exception that ends the program is logged as CRITICAL (priority 2, with its
    traceback), not written to stderr without a priority."""
    if issubclass(kind, KeyboardInterrupt):
        sys.__excepthook__(kind, exc, tb)
        return
    logging.getLogger("grassd").critical("uncaught exception, the program ends",
                                         exc_info=(kind, exc, tb))
