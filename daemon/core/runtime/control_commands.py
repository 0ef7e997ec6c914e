"""The commands of the control socket (see :mod:`grassd.daemon.core.runtime.control` for the
protocol): ``ping``, ``status``, ``reload``, ``calibrate`` and ``bundles_retry``. They run in
socket threads; a calibration, or putting a quarantined bundle back, is queued for the main
loop (a bounded queue, so that clients waiting for runs cannot hold every control-socket slot
and status stays answerable).

Only :data:`READ_ONLY_COMMANDS` may be sent by any client that can connect (the readers'
group); every other command changes the daemon's state and is served only for root and the
daemon's own user: :class:`~grassd.daemon.core.runtime.control.ControlServer` checks the peer's
credentials (``SO_PEERCRED``) before a command gets here.

The wire format's types are here too, where the commands read them (:data:`Request`,
:class:`Answer` and the answers of the commands here, :class:`CommandAnswer`); a feature's
commands answer with a type of its own that adds its keys to :class:`Answer`."""

from __future__ import annotations

import math
import os
import queue
import threading
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Required, TypeAlias, TypedDict

from grassd import __version__
from grassd.daemon.core.monitoring.status_json import StatusJson
from grassd.daemon.core.monitoring.status_types import Status

if TYPE_CHECKING:  # the outcomes (and the fleet, numpy) only where the daemon runs: clients
    # import this module for READ_ONLY_COMMANDS
    from grassd.daemon.core.runtime.outcome import RunOutcome, RunOutcomeJson
    from grassd.daemon.core.store.quarantine import RetryOutcome

    #: what a queued request ends with: a run's outcome, a bundle put back, or what a
    #: feature's task gives (a measurement's report, its JSON form: the feature's type)
    QueuedResult: TypeAlias = RunOutcome | RetryOutcome | dict[str, Any]

#: A value of a JSON document (what :func:`json.loads` gives).
JsonValue: TypeAlias = (str | int | float | bool | None | list["JsonValue"]
                        | dict[str, "JsonValue"])
#: A request as the daemon reads it: a JSON object whose ``"cmd"`` is a string
#: (:func:`~grassd.daemon.core.runtime.control.parse_request` checks that); each command
#: checks the values it reads.
Request: TypeAlias = Mapping[str, JsonValue]


class Answer(TypedDict, total=False):
    """An answer: ``ok``; on failure ``error``, with ``busy`` (try again later) or ``denied``
    (the peer may not send the command). Each command's answer type adds its own keys."""

    ok: Required[bool]
    error: str | None
    busy: bool
    denied: bool


def command(req: Request) -> str:
    """The request's command (its ``"cmd"``, a string once
    :func:`~grassd.daemon.core.runtime.control.parse_request` took it)."""
    return str(req["cmd"])


#: Commands that only read: any client that can connect to the socket may send them. Every
#: other command (``calibrate``, ``reload``, ``bundles_retry``, an unknown one) needs root or
#: the daemon's own user.
READ_ONLY_COMMANDS: frozenset[str] = frozenset({"ping", "status", "content_status"})
#: The longest ``timeout_s`` a client may ask a waiting request to wait (a day).
MAX_WAIT_S = 86400.0


@dataclass
class QueuedRequest:
    """A request the main loop serves: a calibration run (``force``d or not), or ``task``;
    ``done`` is set once ``result`` (the run's or the task's outcome) is there."""

    force: bool
    done: threading.Event = field(default_factory=threading.Event)
    result: QueuedResult | None = None
    #: main-loop work other than a calibration (e.g. putting a quarantined bundle back)
    task: Callable[[], QueuedResult] | None = None


class CommandAnswer(Answer, total=False):
    """The answers of the commands here: ``ping``'s ``pid`` and ``version``, ``status``'s
    ``status``, ``calibrate``'s ``run`` (when it waited) or ``queued`` (requests in the queue),
    ``bundles_retry``'s ``retry``."""

    pid: int
    version: str
    status: StatusJson
    run: RunOutcomeJson | None
    queued: int
    retry: dict[str, object]


class Unanswered(Exception):  # noqa: N818 (what happened to the request)
    """A request queued for the main loop was not served: ``answer`` is the reply saying why
    (the daemon stopping, the queue full, or no result within the request's timeout)."""

    def __init__(self, answer: Answer) -> None:
        super().__init__(answer["error"])
        self.answer = answer


class ControlCommands:
    """Answers control-socket requests: ``status()`` gives the live status (sent in its JSON
    form, :meth:`~grassd.daemon.core.monitoring.status_types.Status.to_json`), ``reload`` sets
    ``reload_event``, ``calibrate`` queues a :class:`QueuedRequest` on ``requests`` (not
    while ``stop_event`` is set), ``bundles_retry`` queues ``retry_bundle(name)``; any other
    command goes to the feature ``feature_for(cmd)`` names (None: unknown), which may queue
    its own work with :meth:`in_main_loop`."""

    def __init__(self, status: Callable[[], Status], reload_event: threading.Event,
                 stop_event: threading.Event, requests: queue.Queue[QueuedRequest],
                 retry_bundle: Callable[[str], RetryOutcome],
                 feature_for: Callable[[str], Callable[[Request], Answer] | None]
                 = lambda _cmd: None) -> None:
        self.status = status
        self.feature_for = feature_for
        self.reload_event = reload_event
        self.stop_event = stop_event
        self.requests = requests
        self.retry_bundle = retry_bundle

    def in_main_loop(self, req: Request, task: Callable[[], QueuedResult],
                     what: str) -> QueuedResult | None:
        """Queue ``task`` for the main loop and wait for its result, at most the request's
        ``timeout_s``; :class:`Unanswered` (its reply naming ``what``) when the daemon is
        stopping, the queue is full or the time is out."""
        if self.stop_event.is_set():
            raise Unanswered({"ok": False, "error": "daemon is stopping"})
        timeout = _timeout(req)
        r = QueuedRequest(force=False, task=task)
        try:
            self.requests.put_nowait(r)
        except queue.Full:
            raise Unanswered({"ok": False, "busy": True,
                              "error": "busy: try again later"}) from None
        if not r.done.wait(timeout):
            raise Unanswered({"ok": False, "error": f"{what} did not finish within "
                                                    f"{timeout:g} s"})
        return r.result

    def handle(self, req: Request) -> Answer:
        """Answer one control-socket request (runs in a socket thread)."""
        try:
            return self._handle(req)
        except Unanswered as exc:
            return exc.answer

    def _handle(self, req: Request) -> Answer:
        cmd = command(req)
        answer: CommandAnswer
        if cmd == "ping":
            answer = {"ok": True, "pid": os.getpid(), "version": __version__}
            return answer
        if cmd == "status":
            answer = {"ok": True, "status": self.status().to_json()}
            return answer
        if cmd == "reload":
            self.reload_event.set()
            return {"ok": True}
        if cmd == "bundles_retry":  # in the main loop, which also claims and prunes bundles
            name = req.get("bundle", "")
            if not isinstance(name, str) or not name:
                raise ValueError('bundles_retry needs "bundle": the name of a quarantined bundle '
                                 "(see `grassd status`)")
            out = _retry_json(self.in_main_loop(req, lambda: self.retry_bundle(name),
                                                "putting the bundle back"))
            error = out.get("error")
            answer = {"ok": out.get("status") == "ok", "retry": out,
                      "error": None if error is None else str(error)}
            return answer
        if cmd == "calibrate":
            if self.stop_event.is_set():
                return {"ok": False, "error": "daemon is stopping"}
            timeout = _timeout(req)  # checked before anything is queued
            r = QueuedRequest(force=bool(req.get("force", False)))
            try:
                self.requests.put_nowait(r)
            except queue.Full:
                return {"ok": False, "busy": True,
                        "error": f"busy: {self.requests.maxsize} calibration requests are "
                                 "already queued; try again after they ran"}
            if not req.get("wait", False):
                answer = {"ok": True, "queued": self.requests.qsize()}
                return answer
            if not r.done.wait(timeout):
                return {"ok": False, "error": f"run did not finish within {timeout:g} s"}
            answer = {"ok": True, "run": _run_json(r.result)}
            return answer
        feature = self.feature_for(cmd)
        if feature is not None:  # measure, content_frame, content_show, ...
            return feature(req)
        if cmd.startswith("content_"):
            return {"ok": False, "error": "the daemon shows no content: set [content] enabled "
                                          "= true in its configuration and reload it"}
        return {"ok": False, "error": f"unknown command {cmd!r} "
                                      "(use ping, status, calibrate, measure, reload, "
                                      "bundles_retry)"}


def _run_json(result: QueuedResult | None) -> RunOutcomeJson | None:
    """The wire form of a calibration request's result (None: none)."""
    from grassd.daemon.core.runtime.outcome import RunOutcome  # where the daemon runs

    if result is None:
        return None
    if not isinstance(result, RunOutcome):
        raise TypeError(f"a calibration ended with {type(result).__name__}, not its outcome")
    return result.to_json()


def _retry_json(result: QueuedResult | None) -> dict[str, object]:
    """The wire form of a bundle put back (empty: none)."""
    from grassd.daemon.core.store.quarantine import RetryOutcome  # where the daemon runs

    if result is None:
        return {}
    if not isinstance(result, RetryOutcome):
        raise TypeError(f"putting a bundle back ended with {type(result).__name__}")
    return result.to_json()


def _timeout(req: Request) -> float:
    """The request's ``timeout_s`` (default 3600 s), a finite number of seconds in
    (0, :data:`MAX_WAIT_S`]; raises :class:`ValueError` naming the fix otherwise."""
    value = req.get("timeout_s", 3600)
    if isinstance(value, bool) or not isinstance(value, int | float) \
            or not math.isfinite(value) or not 0 < value <= MAX_WAIT_S:
        raise ValueError(f'"timeout_s" must be a number of seconds in (0, {MAX_WAIT_S:g}], '
                         f"not {str(value)[:40]!r}")
    return float(value)
