"""Alerts without Prometheus: run ``[alerts] command`` when the health level changes.

The daemon calls :meth:`Alerter.observe` with its
:class:`~grassd.daemon.core.monitoring.health.Health` after every run and reconcile (main thread; it
returns at once). When the level differs from the last one alerted (ok <-> degraded <->
failed), the command runs in a worker thread with a JSON description of the change on its
standard input::

    {"service": "grassd", "host": "kiosk-3", "at": "2026-06-21T12:00:00+00:00",
     "previous": "ok", "level": "degraded", "reasons": ["controller ... unreachable ..."],
     "changes": [{"at": "...", "from": "ok", "to": "degraded", "reasons": [...]}],
     "health": "degraded: controller /dev/ttyACM0#1 unreachable (table 6, not 7): ...",
     "controllers": [{"name": "/dev/ttyACM0#1", "reachable": false, "in_sync": false,
                      "table_id": 6, "error": "..."}, ...],
     "state_dir": "/var/lib/grassd"}

and ``GRASSD_HEALTH`` / ``GRASSD_PREVIOUS_HEALTH`` in its environment. ``changes`` lists the
changes since the last alert (the latest :data:`MAX_CHANGES`). Without a command the levels are
only followed (a command set by a reload starts from the level then current).

Rate limit: at most one run per ``min_interval_s``. Changes meanwhile are summed up in one
alert from the last level alerted to the level then current (``changes`` lists them); a level
that went and came back within the interval alerts nothing. A run still going after
``timeout_s`` is killed. A command that fails (cannot start, exits non-zero, times out) is
logged with its stderr, never fatal, and not retried: the next change alerts again.

The level last alerted is kept in the state database (meta ``alerts.level``), so a restart
neither repeats an alert nor misses a change that happened while the daemon was down. Without
one (a new state directory) the first level seen is taken as known, except ``failed``, which is
alerted.

What the description says may quote a bundle's name (a waiting bundle's reason) chosen by
whoever writes the inbox: every reason, the health line and a controller's name and error
are made one line (:func:`~grassd.daemon.core.safe_text.one_line`), so a consumer that
puts them in a subject line or a chat message gets no forged line and no terminal escape.
"""

from __future__ import annotations

import json
import logging
import os
import shlex
import socket
import subprocess
import threading
import time
from collections import deque
from collections.abc import Iterable
from typing import TypedDict

from grassd.daemon.core.config.settings import AlertsConfig
from grassd.daemon.core.monitoring.health import Health
from grassd.daemon.core.monitoring.status_types import Status
from grassd.daemon.core.safe_text import one_line
from grassd.daemon.core.store.history import History
from grassd.daemon.core.timestamps import utc_iso

log = logging.getLogger(__name__)

#: meta key of the state database holding the level last alerted
META_KEY = "alerts.level"
#: changes listed in one alert (the oldest are dropped beyond it)
MAX_CHANGES = 50


#: one change of health between two alerts: ``at`` (ISO 8601), ``from`` and ``to`` levels and
#: the ``reasons`` of the new one (a TypedDict by its call: "from" is a Python keyword)
HealthChange = TypedDict("HealthChange", {"at": str, "from": str | None, "to": str,
                                          "reasons": list[str]})


class AlertController(TypedDict):
    """A controller as the alert describes it."""

    name: str | None
    reachable: bool
    in_sync: bool
    table_id: int | None
    error: str | None


class AlertEvent(TypedDict):
    """The JSON description of a health change on the alert command's standard input."""

    service: str
    host: str
    at: str
    previous: str
    level: str
    reasons: list[str]
    changes: list[HealthChange]
    health: str | None
    controllers: list[AlertController]
    state_dir: str | None


def _text(v: str | None) -> str | None:
    """A text of the description made one line (None stays None)."""
    return None if v is None else one_line(v, None)


def _lines(texts: Iterable[str]) -> list[str]:
    """Reasons, each made one line."""
    return [one_line(t, None) for t in texts]


class Alerter:
    """Runs ``cfg.command`` on health changes (module docstring); ``history`` keeps the level
    last alerted."""

    def __init__(self, cfg: AlertsConfig, history: History) -> None:
        self.cfg = cfg
        self.history = history
        self._alerted: str | None = history.get_meta(META_KEY)
        self._current: str | None = None
        self._changes: deque[HealthChange] = deque(maxlen=MAX_CHANGES)
        self._last_run = -float("inf")  # monotonic s
        self._worker: threading.Thread | None = None
        #: the latest finished runs: (argv, exit status or None when it could not run, stderr)
        self.runs: deque[tuple[list[str], int | None, str]] = deque(maxlen=MAX_CHANGES)

    def configure(self, cfg: AlertsConfig) -> None:
        """Take a reloaded ``[alerts]`` (the level last alerted and pending changes stay)."""
        self.cfg = cfg

    def observe(self, health: Health, status: Status | None = None,
                now: float | None = None) -> bool:
        """Note ``health`` (with ``status`` for the description); start the alert command when
        due (see the module docstring). Returns True when it started one. Never blocks."""
        now = time.monotonic() if now is None else now
        level = health.level
        if self.cfg.command is None:  # no alerts: only follow, so that one set later starts
            self._current = self._alerted = level  # from the level then current
            self._changes.clear()
            return False
        if self._alerted is None:  # a new state directory: take the first level as known
            if level != "failed":
                self._current = level
                self._remember(level)
                return False
            self._alerted = self._current = "ok"
        if level != self._current:
            self._changes.append({"at": utc_iso(time.time()), "from": self._current or
                                  self._alerted, "to": level,
                                  "reasons": _lines(health.reasons)})
            self._current = level
        if level == self._alerted:
            self._changes.clear()  # back where the last alert left it: nothing to say
            return False
        if (now - self._last_run < self.cfg.min_interval_s
                or (self._worker is not None and self._worker.is_alive())):
            return False
        event: AlertEvent = {
            "service": "grassd", "host": socket.gethostname(), "at": utc_iso(time.time()),
            "previous": self._alerted, "level": level, "reasons": _lines(health.reasons),
            "changes": list(self._changes),
            "health": None if status is None else _text(status.health.summary()),
            "controllers": [] if status is None else [
                {"name": _text(c.name), "reachable": c.reachable, "in_sync": c.in_sync,
                 "table_id": c.table_id, "error": _text(c.error)}
                for c in status.controllers],
            "state_dir": None if status is None else status.state_dir,
        }
        argv = shlex.split(self.cfg.command)
        self._worker = threading.Thread(target=self._run, args=(argv, event), daemon=True,
                                        name="alert-command")
        self._worker.start()
        self._last_run = now
        self._changes.clear()
        self._remember(level)
        log.info("health %s -> %s: alert command %s started", event["previous"], level,
                 argv[0])
        return True

    def _remember(self, level: str) -> None:
        self._alerted = level
        try:
            self.history.set_meta(META_KEY, level)
        except Exception as exc:  # e.g. a full disk: alerting goes on
            log.warning("alerts: cannot store the level alerted (%s): %s", level, exc)

    def _run(self, argv: list[str], event: AlertEvent) -> None:
        env = {**os.environ, "GRASSD_HEALTH": event["level"],
               "GRASSD_PREVIOUS_HEALTH": event["previous"]}
        data = json.dumps(event, indent=2).encode()
        try:
            r = subprocess.run(argv, input=data, capture_output=True, env=env,
                               timeout=self.cfg.timeout_s, check=False)
        except subprocess.TimeoutExpired as exc:
            err = (exc.stderr or b"").decode(errors="replace").strip()
            log.error("alert command %s killed after %g s (health %s -> %s)%s", argv[0],
                      self.cfg.timeout_s, event["previous"], event["level"],
                      f": {err}" if err else "")
            self.runs.append((argv, None, f"timed out after {self.cfg.timeout_s:g} s"))
            return
        except OSError as exc:
            log.error("alert command %s cannot run: %s (set [alerts] command to an "
                      "executable program)", argv[0], exc.strerror or exc)
            self.runs.append((argv, None, str(exc)))
            return
        err = r.stderr.decode(errors="replace").strip()
        if r.returncode != 0:
            log.error("alert command %s failed with exit status %d (health %s -> %s)%s",
                      argv[0], r.returncode, event["previous"], event["level"],
                      f": {err[-500:]}" if err else "")
        self.runs.append((argv, r.returncode, err))

    def wait(self, timeout_s: float | None = None) -> None:
        """Wait for a running alert command (at shutdown, and in tests)."""
        w = self._worker
        if w is not None:
            w.join(timeout_s)
