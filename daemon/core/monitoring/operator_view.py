"""What the daemon shows its operator after every run and reconcile: the metrics textfile
(:mod:`grassd.daemon.core.monitoring.metrics`), the alert command on health changes
(:mod:`grassd.daemon.core.monitoring.alerts`) and the status page
(:mod:`grassd.daemon.core.monitoring.status_page`).

The view never reads the live service: it is given the configuration, the history and a
function that returns an :class:`OperatorSnapshot` (the service's status, the lux sensor's
state and the capture station's last success, taken at once). The service calls
:meth:`OperatorView.after_run` after each run (whatever its outcome) and
:meth:`OperatorView.after_reconcile` after each reconcile, both in its main thread. Neither
ever raises: a file that cannot be written is logged (once per distinct error) and the daemon
goes on. The status page is regenerated after every run, and after a reconcile only when the
health or a controller's state changed (its trend plots cost more than the metrics), or when
a feature's card has news (``cards``, which the service gives: the content's fresh picture of
the display, read every few seconds while content plays).

With a capture station (``[capture]``), the metric
``grassd_capture_last_success_timestamp_seconds`` says when it last delivered a bundle; it is
not written before the first delivery, nor without a station.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Protocol

from grassd.daemon.core.config.settings import Config
from grassd.daemon.core.monitoring.alerts import Alerter
from grassd.daemon.core.monitoring.health import Health
from grassd.daemon.core.monitoring.metrics import (
    SensorState,
    registry,
    textfile_path,
    write_textfile,
)
from grassd.daemon.core.monitoring.page_parts import Card, Clock
from grassd.daemon.core.monitoring.status_page import render, write_page
from grassd.daemon.core.monitoring.status_types import Status
from grassd.daemon.core.store.history import History
from grassd.daemon.core.store.layout import StateLayout

if TYPE_CHECKING:
    from grassd.daemon.core.hardware.fleet import ControllerReport

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class OperatorSnapshot:
    """What the operator's outputs show, taken at one moment by the service: its ``status``,
    the Modbus lux ``sensor``'s state (None: no sensor configured) and ``capture_at``, when the
    capture station last delivered a bundle (epoch s; None: no station, or none yet)."""

    status: Status
    sensor: SensorState | None = None
    capture_at: float | None = None


class PageCards(Protocol):
    """The features' sections of the status page, as the service gives them."""

    def news(self) -> bool:
        """Whether a card has news since the page was last written (the page is then
        written again)."""
        ...

    def cards(self, clock: Clock) -> Sequence[Card]:
        """Every feature's card now, its times in ``clock``."""
        ...


class OperatorView:
    """Metrics, alerts and status page of the daemon configured by ``cfg``, keeping its
    ``history``; ``snapshot`` returns the daemon's state at the moment it is called (it may
    raise, e.g. on an unreadable database: logged, nothing written); ``cards`` the features'
    sections of the page (None: none)."""

    def __init__(self, cfg: Config, history: History,
                 snapshot: Callable[[], OperatorSnapshot],
                 cards: PageCards | None = None) -> None:
        self.cfg = cfg
        self.history = history
        self.snapshot = snapshot
        self.cards = cards
        self.alerter = Alerter(cfg.alerts, history)
        #: failed pushes per controller name since the daemon started
        self.push_failures: dict[str, int] = {}
        self.health: Health | None = None
        self._page_key: tuple | None = None
        self._errors: dict[str, str] = {}

    @property
    def textfile(self) -> Path:
        """Where the metrics are written (``[metrics] textfile`` or its default)."""
        return textfile_path(self.cfg.metrics.textfile, self.cfg.state_dir)

    @property
    def page(self) -> Path:
        """Where the status page is written: ``<state_dir>/reports/index.html``."""
        return StateLayout(self.cfg.state_dir).status_page

    def configure(self, cfg: Config) -> None:
        """Take a reloaded configuration (``[alerts]``; ``[metrics]``, the state directory and
        the site's time zone are read at each write)."""
        self.cfg = cfg
        self.alerter.configure(cfg.alerts)

    def after_run(self, reports: Iterable[ControllerReport] = ()) -> None:
        """After a run whose push made ``reports`` (none: it pushed nothing, or a
        measurement, whose run pushes on its own): count failed pushes, write metrics and
        page, alert on a change."""
        self._count(reports)
        self._update(page=True)

    def after_reconcile(self, reports: Iterable[ControllerReport]) -> None:
        """After a reconcile with ``reports``: count failed pushes, write metrics, alert on a
        change; the page when state changed."""
        self._count(reports)
        self._update(page=False)

    def _count(self, reports: Iterable[ControllerReport]) -> None:
        """A push failed: the controller did not end with its table, and the attempt was not
        held back by its backoff (see :mod:`grassd.daemon.core.hardware.fleet`)."""
        for r in reports:
            if not r.ok and r.retry_in_s is None:
                self.push_failures[r.controller] = self.push_failures.get(r.controller, 0) + 1

    def _snapshot(self) -> OperatorSnapshot | None:
        try:
            return self.snapshot()
        except Exception as exc:  # e.g. the database is unreadable: nothing to show
            self._failed("status", f"cannot read the daemon's status: {exc}")
            return None

    def _update(self, page: bool) -> None:
        snap = self._snapshot()
        if snap is None:
            return
        status = snap.status
        self.health = health = status.health
        self.alerter.observe(health, status)
        self._write_metrics(snap)
        key = (health, tuple((c.name, c.reachable, c.in_sync, c.table_id)
                             for c in status.controllers))
        news = self._news()  # asked every time: a card's reading is taken when it is due
        if page or key != self._page_key or news:
            self._write_page(status)
            self._page_key = key

    def _news(self) -> bool:
        """A feature's card has news (never raises: a failure is logged once)."""
        if self.cards is None:
            return False
        try:
            news = self.cards.news()
        except Exception as exc:  # the page is written without the news
            self._failed("cards", f"cannot update a card of the status page: {exc}")
            return False
        self._cleared("cards")
        return news

    def _write_metrics(self, snap: OperatorSnapshot, up: bool = True) -> None:
        path = self.textfile
        try:
            reg = registry(snap.status, self.history, push_failures=self.push_failures,
                           sensor=snap.sensor, capture_at=snap.capture_at, up=up)
            write_textfile(path, reg)
        except Exception as exc:
            self._failed("metrics", f"cannot write the metrics to {path}: {exc} (set "
                                    "[metrics] textfile to a writable *.prom file)")
        else:
            self._cleared("metrics")

    def _write_page(self, status: Status) -> None:
        try:
            tz = self.cfg.site.timezone
            cards = () if self.cards is None else self.cards.cards(Clock(tz))
            text = render(status, self.history, timezone=tz,
                          push_failures=self.push_failures, cards=cards)
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
        snap = self._snapshot()
        if snap is not None:
            self._write_metrics(snap, up=False)
        self.alerter.wait(timeout_s)
