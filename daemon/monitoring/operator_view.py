"""What the daemon shows its operator after every run and reconcile: the metrics textfile
(:mod:`grassd.daemon.monitoring.metrics`), the alert command on health changes
(:mod:`grassd.daemon.monitoring.alerts`) and the status page
(:mod:`grassd.daemon.monitoring.status_page`).

The service calls :meth:`OperatorView.after_run` after each run (whatever its outcome) and
:meth:`OperatorView.after_reconcile` after each reconcile, both in its main thread. Neither
ever raises: a file that cannot be written is logged (once per distinct error) and the daemon
goes on. The status page is regenerated after every run, and after a reconcile only when the
health or a controller's state changed (its trend plots cost more than the metrics).

With a capture station (``[capture]``, the service's ``capture_loop``), the metric
``grassd_capture_last_success_timestamp_seconds`` says when it last delivered a bundle; it is
not written before the first delivery, nor without a station.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

from grassd.daemon.config.settings import Config
from grassd.daemon.monitoring.alerts import Alerter
from grassd.daemon.monitoring.health import Health, assess
from grassd.daemon.monitoring.metrics import SensorState, registry, textfile_path, write_textfile
from grassd.daemon.monitoring.status_page import PAGE_NAME, render, write_page

if TYPE_CHECKING:
    from grassd.daemon.runtime.service import Service

log = logging.getLogger(__name__)


class OperatorView:
    """Metrics, alerts and status page of the daemon ``service`` (reads its ``status()``,
    ``history``, ``cfg``, ``sensor`` and ``reports_dir``)."""

    def __init__(self, service: Service) -> None:
        self.service = service
        self.alerter = Alerter(service.cfg.alerts, service.history)
        #: failed pushes per controller name since the daemon started
        self.push_failures: dict[str, int] = {}
        self.health: Health | None = None
        self._page_key: tuple | None = None
        self._errors: dict[str, str] = {}

    @property
    def textfile(self) -> Path:
        """Where the metrics are written (``[metrics] textfile`` or its default)."""
        cfg: Config = self.service.cfg
        return textfile_path(cfg.metrics.textfile, cfg.state_dir)

    @property
    def page(self) -> Path:
        """Where the status page is written: ``<state_dir>/reports/index.html``."""
        return self.service.reports_dir / PAGE_NAME

    def configure(self, cfg: Config) -> None:
        """Take a reloaded configuration (``[alerts]``; ``[metrics]`` is read at each write)."""
        self.alerter.configure(cfg.alerts)

    def after_run(self, result: Mapping[str, Any]) -> None:
        """After a run with ``result`` (the service's run result; its ``controllers`` are the
        push reports): count failed pushes, write metrics and page, alert on a change."""
        self._count(result.get("controllers") or [])
        self._update(page=True)

    def after_reconcile(self, reports: Iterable[Any]) -> None:
        """After a reconcile with ``reports`` (:class:`~grassd.daemon.fleet.ControllerReport`):
        count failed pushes, write metrics, alert on a change; the page when state changed."""
        self._count(r.__dict__ for r in reports)
        self._update(page=False)

    def _count(self, reports: Iterable[Mapping[str, Any]]) -> None:
        """A push failed: the controller did not end with its table, and the attempt was not
        held back by its backoff (see :mod:`grassd.daemon.hardware.fleet`)."""
        for r in reports:
            if not r["ok"] and r.get("retry_in_s") is None:
                name = r["controller"]
                self.push_failures[name] = self.push_failures.get(name, 0) + 1

    def _status(self) -> Mapping[str, Any] | None:
        try:
            return self.service.status()
        except Exception as exc:  # e.g. the database is unreadable: nothing to show
            self._failed("status", f"cannot read the daemon's status: {exc}")
            return None

    def _update(self, page: bool) -> None:
        status = self._status()
        if status is None:
            return
        self.health = health = assess(status)
        self.alerter.observe(health, status)
        self._write_metrics(status, health)
        key = (health, tuple((c["name"], c["reachable"], c["in_sync"], c["table_id"])
                             for c in status["controllers"]))
        if page or key != self._page_key:
            self._write_page(status, health)
            self._page_key = key

    def _sensor(self) -> SensorState | None:
        s = self.service.sensor
        if s is None:
            return None
        return SensorState(up=s.last_ok, last_success_at=s.last_success_at)

    def _write_metrics(self, status: Mapping[str, Any], health: Health,
                       up: bool = True) -> None:
        path = self.textfile
        try:
            loop = self.service.capture_loop
            capture = None if loop is None else loop.last_success_at
            reg = registry(status, health, self.service.history,
                           push_failures=self.push_failures, sensor=self._sensor(),
                           capture_at=capture, up=up)
            write_textfile(path, reg)
        except Exception as exc:
            self._failed("metrics", f"cannot write the metrics to {path}: {exc} (set "
                                    "[metrics] textfile to a writable *.prom file)")
        else:
            self._cleared("metrics")

    def _write_page(self, status: Mapping[str, Any], health: Health) -> None:
        try:
            text = render(status, health, self.service.history,
                          timezone=self.service.cfg.site.timezone,
                          push_failures=self.push_failures)
            write_page(self.page, text)
        except Exception as exc:
            self._failed("page", f"cannot write the status page {self.page}: {exc}")
        else:
            self._cleared("page")

    def _failed(self, what: str, msg: str) -> None:
        if self._errors.get(what) != msg:
            log.warning("%s (the daemon keeps running)", msg)
            self._errors[what] = msg

    def _cleared(self, what: str) -> None:
        if self._errors.pop(what, None) is not None:
            log.info("%s written again", what)

    def close(self, timeout_s: float = 5.0) -> None:
        """At a clean stop: write the metrics once more with ``grassd_up`` 0 and wait up to
        ``timeout_s`` for a running alert command."""
        status = self._status()
        if status is not None:
            self._write_metrics(status, assess(status), up=False)
        self.alerter.wait(timeout_s)
