"""The daemon's own measurements: ``[measure] interval_s`` schedules one within the local hours
``start_hour`` .. ``end_hour``, and the control socket's ``measure`` command runs one in the
main loop and answers with its report. An in-process daemon on simulated hardware; the
measurement itself fails fast here (the camera was never set up), which is enough to see when
and by whom it runs: its report names the trigger."""

from __future__ import annotations

import threading
import time
from datetime import datetime
from pathlib import Path
from zoneinfo import ZoneInfo

from daemon_harness import service, write_config

from grassd.daemon.errors import ControlError
from grassd.daemon.monitoring.measurement_report import load_reports
from grassd.daemon.runtime.control import ControlServer, request
from grassd.daemon.store.layout import StateLayout

#: the daemon's site time zone (write_config's configuration has none: the default)
TZ = "UTC"


def _config(tmp_path: Path, cfg, hours: tuple[int, int]) -> Path:
    return write_config(tmp_path / "grassd.toml", tmp_path / "state", cfg, extra=(
        '[measure]\ncamera = "http://127.0.0.1:9"\ninterval_s = 3600\n'
        f"start_hour = {hours[0]}\nend_hour = {hours[1]}\n"))


def _reports(tmp_path: Path) -> list[dict]:
    return load_reports(StateLayout(tmp_path / "state"))


def test_a_measurement_runs_once_its_interval_has_passed_within_its_hours(tmp_path, hw):
    sim, cfg = hw
    hour = datetime.now(ZoneInfo(TZ)).hour
    svc = service(_config(tmp_path, cfg, (hour, (hour + 1) % 24)))
    try:
        assert svc.cfg.site.timezone == TZ
        svc.tick()
        assert _reports(tmp_path) == []  # the interval counts from the daemon's start
        svc.last_measure_at = time.time() - 3601  # as if the last one was an hour ago
        svc.tick()
        [report] = _reports(tmp_path)
        assert report["trigger"] == "interval" and report["status"] == "failed"
        assert "grassd measure setup" in report["error"]
        svc.tick()  # the next one is an interval away
        assert len(_reports(tmp_path)) == 1
    finally:
        svc.shutdown()


def test_no_measurement_outside_its_hours(tmp_path, hw):
    sim, cfg = hw
    hour = datetime.now(ZoneInfo(TZ)).hour
    svc = service(_config(tmp_path, cfg, ((hour + 2) % 24, (hour + 3) % 24)))
    try:
        svc.last_measure_at = time.time() - 10 * 3600
        svc.tick()
        assert _reports(tmp_path) == []
    finally:
        svc.shutdown()


def test_the_control_socket_measures_in_the_main_loop(tmp_path, hw):
    sim, cfg = hw
    hour = datetime.now(ZoneInfo(TZ)).hour
    svc = service(_config(tmp_path, cfg, ((hour + 2) % 24, (hour + 3) % 24)))
    server = ControlServer(tmp_path / "control.sock", svc.handle_request).start()
    answer: list[BaseException] = []

    def ask() -> None:
        try:
            request(server.path, {"cmd": "measure", "timeout_s": 60}, timeout_s=90)
        except ControlError as exc:  # a failed measurement is the daemon's error
            answer.append(exc)

    client = threading.Thread(target=ask)
    try:
        client.start()
        deadline = time.monotonic() + 60
        while client.is_alive() and time.monotonic() < deadline:
            svc.tick()  # the main loop serves the queued measurement
            client.join(0.05)
        assert not client.is_alive(), "the measure request was never answered"
        [error] = answer
        assert "grassd measure setup" in str(error)
        [report] = _reports(tmp_path)
        assert report["trigger"] == "request" and report["status"] == "failed"
    finally:
        server.stop()
        svc.shutdown()
