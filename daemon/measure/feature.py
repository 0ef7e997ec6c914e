"""Measurements as they join the daemon (:class:`~grassd.daemon.core.runtime.features
.Feature`): one every ``[measure] interval_s`` within its hours, and one on the control
socket's ``measure`` command, each in the main loop with the display held from the other
features (:func:`~grassd.daemon.measure.job.measure_with`); the last one's card on the status
page (:mod:`~grassd.daemon.measure.card`)."""

from __future__ import annotations

import time
from datetime import datetime
from typing import TYPE_CHECKING, cast
from zoneinfo import ZoneInfo

from grassd.daemon.core.runtime.control_commands import Answer, Request
from grassd.daemon.core.runtime.features import Feature

if TYPE_CHECKING:
    from grassd.daemon.core.monitoring.page_parts import Card, Clock
    from grassd.daemon.core.runtime.service import Service
    from grassd.daemon.measure.report import MeasurementReport


class MeasureAnswer(Answer, total=False):
    """The ``measure`` command's answer: the measurement's report."""

    measurement: MeasurementReport


class MeasureFeature(Feature):
    """Runs the daemon's measurements (module docstring); ``last_at`` the start of the last
    one (epoch s), read from the newest report at the first look."""

    name = "measure"

    def __init__(self) -> None:
        self.last_at: float | None = None

    def tick(self, svc: Service) -> None:
        """Measure when a scheduled measurement is due (:meth:`due`)."""
        if self.due(svc):
            self.now(svc, "interval")

    def due(self, svc: Service) -> bool:
        """A scheduled measurement is due: ``[measure] interval_s`` since the last one (or the
        daemon's start), within the local hours ``start_hour`` .. ``end_hour``."""
        mc = svc.cfg.measure
        if mc is None or mc.interval_s <= 0:
            return False
        if self.last_at is None:
            from grassd.daemon.core.store.layout import StateLayout
            from grassd.daemon.measure.report import epoch_of, load_reports

            last = load_reports(StateLayout(svc.cfg.state_dir), limit=1)
            self.last_at = (epoch_of(last[-1].get("started_at")) if last else None
                            ) or svc.started_at
        now = time.time()
        hour = datetime.fromtimestamp(now, ZoneInfo(svc.cfg.site.timezone)).hour
        return now - self.last_at >= mc.interval_s and mc.in_window(hour)

    def now(self, svc: Service, trigger: str = "request") -> MeasurementReport:
        """Measure the display now, the other features holding off it; the measurement's
        report (JSON-ready). Then the status page's measurement card is written again."""
        from grassd.daemon.measure.job import measure_with

        svc._progress(f"{trigger} measurement of the display")
        self.last_at = time.time()
        try:
            with svc.features.display_held(by=self):
                return measure_with(svc, trigger)
        finally:
            svc.operator.after_run()

    def card(self, svc: Service, clock: Clock) -> Card:
        """The last measurement's card (:func:`~grassd.daemon.measure.card.measurement_card`),
        "never measured" before the first."""
        from grassd.daemon.measure.card import measurement_card

        return measurement_card(svc.cfg.state_dir, clock)

    def handles(self, cmd: str) -> bool:
        """``measure``."""
        return cmd == "measure"

    def handle(self, svc: Service, req: Request) -> MeasureAnswer:
        """``{"cmd": "measure", "timeout_s": s}``: a measurement in the main loop, like a
        run; its report under ``measurement``."""
        done = svc.commands.in_main_loop(req, lambda: self.now(svc), "measurement")
        assert isinstance(done, dict)
        report = cast("MeasurementReport", done)  # what self.now returned
        return {"ok": report.get("status") == "ok", "measurement": report,
                "error": report.get("error")}
