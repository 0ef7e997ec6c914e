"""The commands of the control socket (see :mod:`grassd.daemon.runtime.control` for the
protocol): ``ping``, ``status``, ``reload``, ``calibrate`` and ``bundles_retry``. They run in
socket threads; a calibration, or putting a quarantined bundle back, is queued for the main
loop (a bounded queue, so that clients waiting for runs cannot hold every control-socket slot
and status stays answerable)."""

from __future__ import annotations

import os
import queue
import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from grassd import __version__


@dataclass
class QueuedRequest:
    """A request the main loop serves: a calibration run (``force``d or not), or ``task``;
    ``done`` is set once ``result`` (the run's or the task's outcome) is there."""

    force: bool
    done: threading.Event = field(default_factory=threading.Event)
    result: dict[str, Any] | None = None
    #: main-loop work other than a calibration (e.g. putting a quarantined bundle back)
    task: Callable[[], dict[str, Any]] | None = None


class ControlCommands:
    """Answers control-socket requests: ``status()`` gives the live status, ``reload`` sets
    ``reload_event``, ``calibrate`` queues a :class:`QueuedRequest` on ``requests`` (not
    while ``stop_event`` is set), ``bundles_retry`` queues ``retry_bundle(name)``."""

    def __init__(self, status: Callable[[], dict[str, Any]], reload_event: threading.Event,
                 stop_event: threading.Event, requests: queue.Queue[QueuedRequest],
                 retry_bundle: Callable[[str], dict[str, Any]]) -> None:
        self.status = status
        self.reload_event = reload_event
        self.stop_event = stop_event
        self.requests = requests
        self.retry_bundle = retry_bundle

    def handle(self, req: dict[str, Any]) -> dict[str, Any]:
        """Answer one control-socket request (runs in a socket thread)."""
        cmd = req["cmd"]
        if cmd == "ping":
            return {"ok": True, "pid": os.getpid(), "version": __version__}
        if cmd == "status":
            return {"ok": True, "status": self.status()}
        if cmd == "reload":
            self.reload_event.set()
            return {"ok": True}
        if cmd == "bundles_retry":  # in the main loop, which also claims and prunes bundles
            name = str(req.get("bundle", ""))
            r = QueuedRequest(force=False, task=lambda: self.retry_bundle(name))
            try:
                self.requests.put_nowait(r)
            except queue.Full:
                return {"ok": False, "busy": True, "error": "busy: try again later"}
            if not r.done.wait(float(req.get("timeout_s", 3600))):
                return {"ok": False, "error": "the daemon did not get to it in time"}
            out = r.result or {}
            return {"ok": out.get("status") == "ok", "retry": out, "error": out.get("error")}
        if cmd == "calibrate":
            if self.stop_event.is_set():
                return {"ok": False, "error": "daemon is stopping"}
            r = QueuedRequest(force=bool(req.get("force", False)))
            try:
                self.requests.put_nowait(r)
            except queue.Full:
                return {"ok": False, "busy": True,
                        "error": f"busy: {self.requests.maxsize} calibration requests are "
                                 "already queued; try again after they ran"}
            if not req.get("wait", False):
                return {"ok": True, "queued": self.requests.qsize()}
            timeout = float(req.get("timeout_s", 3600))
            if not r.done.wait(timeout):
                return {"ok": False, "error": f"run did not finish within {timeout:g} s"}
            return {"ok": True, "run": r.result}
        return {"ok": False, "error": f"unknown command {cmd!r} "
                                      "(use ping, status, calibrate, reload, bundles_retry)"}
