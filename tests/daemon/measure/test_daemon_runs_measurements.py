"""The daemon's own measurements: ``[measure] interval_s`` schedules one within the local hours
``start_hour`` .. ``end_hour``, and the control socket's ``measure`` command runs one in the
main loop and answers with its report. An in-process daemon on simulated hardware; the
measurement itself fails fast here (the camera was never set up), which is enough to see when
and by whom it runs: its report names the trigger."""

from __future__ import annotations

import contextlib
import threading
import time
from collections.abc import Iterator
from datetime import datetime
from pathlib import Path
from zoneinfo import ZoneInfo

from daemon_harness import service, write_config

from grassd.daemon.core.errors import ControlError
from grassd.daemon.core.runtime.control import ControlServer, request
from grassd.daemon.core.runtime.service import Service
from grassd.daemon.core.store.layout import StateLayout
from grassd.daemon.measure.report import load_reports

#: the daemon's site time zone (write_config's configuration has none: the default)
TZ = "UTC"


@contextlib.contextmanager
def _daemon(tmp_path: Path, cfg, hours_from_now: int) -> Iterator[Service]:
    """An in-process daemon measuring every hour (``interval_s`` 3600) within a 2-hour window
    that starts ``hours_from_now`` hours from the current local hour (0: it is open now,
    and stays open if the hour turns during the test)."""
    start = (datetime.now(ZoneInfo(TZ)).hour + hours_from_now) % 24
    svc = service(write_config(tmp_path / "grassd.toml", tmp_path / "state", cfg, extra=(
        '[measure]\ncamera = "http://127.0.0.1:9"\ninterval_s = 3600\n'
        f"start_hour = {start}\nend_hour = {(start + 2) % 24}\n")))
    try:
        assert svc.cfg.site.timezone == TZ
        yield svc
    finally:
        svc.shutdown()


def _reports(tmp_path: Path) -> list[dict]:
    return load_reports(StateLayout(tmp_path / "state"))


def test_a_measurement_runs_once_its_interval_has_passed_within_its_hours(tmp_path, hw):
    sim, cfg = hw
    with _daemon(tmp_path, cfg, 0) as svc:
        svc.tick()
        assert _reports(tmp_path) == []  # the interval counts from the daemon's start
        svc.features.get("measure").last_at = time.time() - 3601  # the last an hour ago
        svc.tick()
        [report] = _reports(tmp_path)
        assert report["trigger"] == "interval" and report["status"] == "failed"
        assert "grassd measure setup" in report["error"]
        svc.tick()  # the next one is an interval away
        assert len(_reports(tmp_path)) == 1


def test_no_measurement_outside_its_hours(tmp_path, hw):
    sim, cfg = hw
    with _daemon(tmp_path, cfg, 3) as svc:  # opens in 3 hours, at the earliest 2 from now
        svc.features.get("measure").last_at = time.time() - 10 * 3600
        svc.tick()
        assert _reports(tmp_path) == []


def test_the_control_socket_measures_in_the_main_loop(tmp_path, hw):
    sim, cfg = hw
    with _daemon(tmp_path, cfg, 3) as svc:  # no scheduled one: only the request measures
        _request_a_measurement(tmp_path, svc)
    [report] = _reports(tmp_path)
    assert report["trigger"] == "request" and report["status"] == "failed"


def _request_a_measurement(tmp_path: Path, svc: Service) -> None:
    """Ask ``svc``'s control socket to measure while its main loop runs; the measurement
    fails (the camera was never set up) and the client gets its error."""
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
    finally:
        server.stop()
