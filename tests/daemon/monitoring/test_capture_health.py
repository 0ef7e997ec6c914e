"""A capture station whose last capture failed (after its retries) degrades the health: the
light stops arriving and the table goes stale, so the operator must hear of it."""

from __future__ import annotations

from status_samples import controller, daemon_state, status

from grassd.daemon.core.monitoring.health import assess


def with_capture(capture):
    return status(controller("bus0#1"), daemon=daemon_state(capture=capture))


def test_failed_capture_degrades_and_names_the_camera():
    capture = {"camera": "http://192.168.1.1", "last_error": "camera http://192.168.1.1/osc/"
               "info is unreachable (timed out)", "captures": 4}
    h = assess(with_capture(capture))
    assert h.level == "degraded"
    assert h.reasons == ("capture station http://192.168.1.1: " + capture["last_error"],)


def test_working_capture_station_keeps_ok():
    capture = {"camera": "http://192.168.1.1", "last_error": None, "captures": 4}
    assert assess(with_capture(capture)).level == "ok"
    assert assess(with_capture(None)).level == "ok"
