"""A measurement has a deadline as a whole (``[measure] deadline_s``): a camera that answers
each shot slowly, however far within its own timeouts, is cut at the deadline, in the middle of
a shot; the display is given back (PATTERN_END, long before the controllers' watchdog) and the
report says why. And the photos of only the newest ``[measure] keep_photos`` measurements are
kept.

Simulated controllers on ptys, the lux sensor over Modbus/TCP and a simulated OSC camera over
HTTP on 127.0.0.1, photographing the site panorama (no display in it: these measurements end
before their photos are analysed)."""

from __future__ import annotations

import json
import time
from datetime import datetime
from pathlib import Path

from daemon_harness import write_config

from grassd.daemon.cli.features import daemon_features
from grassd.daemon.core.config.settings import load_config
from grassd.daemon.core.runtime.service import Service
from grassd.daemon.core.store.atomic import atomic_write_json
from grassd.daemon.core.store.layout import StateLayout
from grassd.daemon.measure.camera_chain import Exposure, MeasureSetup
from grassd.rigs.simulated_camera import start_site_camera

#: the controllers' watchdog here (s): far longer than the test, so only PATTERN_END ends it
WATCHDOG_S = 600.0
DEADLINE_S = 10.0


def _site(tmp_path: Path, cfg, camera_url: str, extra: str = "") -> Path:
    path = write_config(tmp_path / "grassd.toml", tmp_path / "state", cfg, extra=(
        f'[measure]\ncamera = "{camera_url}"\npattern_timeout_s = {WATCHDOG_S}\n'
        f"settle_s = 10\npatterns = 4\n{extra}"))
    setup = MeasureSetup((1.0, 1.0, 1.0, 1.0), 1.0, Exposure(0.01, 100, 5.6), 2500.0,
                         ((1.0, 0, 0), (0, 1.0, 0), (0, 0, 1.0)), "spydercheckr-24", "x.dng",
                         "2026-11-27T00:00:00+00:00")
    atomic_write_json(StateLayout(tmp_path / "state").measure_setup, setup.to_json())
    return path


def _measure(path: Path) -> dict:
    svc = Service(load_config(path), features=daemon_features())
    try:
        return svc.features.get("measure").now(svc)
    finally:
        svc.shutdown()


def _in_pattern(sim) -> bool:
    return any(c.in_pattern for bus in sim.buses for c in bus.controllers)


def test_a_slow_camera_is_cut_at_the_deadline_and_the_display_given_back(tmp_path, hw):
    sim, cfg = hw
    camera = start_site_camera(sim)
    scene, seen, asked = camera.scene_source, [], []

    def slow() -> object:  # each shot answered 3 s late: well within every camera timeout
        seen.append(_in_pattern(sim))
        asked.append(time.monotonic())
        time.sleep(3.0)
        return camera.env if scene is None else scene()

    camera.scene_source = slow
    try:
        path = _site(tmp_path, cfg, camera.url, f"deadline_s = {DEADLINE_S}\n")
        report = _measure(path)
        ended = time.monotonic()
    finally:
        camera.stop()
    assert report["status"] == "failed", report
    assert "deadline_s = 10 s" in report["error"] and "photographing" in report["error"]
    assert seen and all(seen)  # the display was in test patterns while photographed
    assert not _in_pattern(sim)  # given back at once, not by the 600 s watchdog
    assert ended - asked[-1] < 3.0  # cut in the middle of a shot, not after it
    took = (datetime.fromisoformat(report["finished_at"])
            - datetime.fromisoformat(report["started_at"])).total_seconds()
    assert took <= DEADLINE_S + 2.0, took  # (whole seconds)
    layout = StateLayout(tmp_path / "state")
    assert not layout.correction.exists()
    assert json.loads(Path(report["report"]).read_text())["error"] == report["error"]


def test_only_the_newest_measurements_keep_their_photos(tmp_path, hw):
    """Three older measurements' photos and reports lie in measure/; a new one (which ends
    after two shots: the light changed) leaves the photos of the newest two (keep_photos),
    every report, the set-up and what is not a measurement's folder."""
    sim, cfg = hw
    camera = start_site_camera(sim)
    scene, calls = camera.scene_source, []

    def light_changes() -> object:
        calls.append(1)
        if len(calls) == 2:
            sim.sensor.lux = 9000.0  # read after this shot: over steady_lux from 2500
        return camera.env if scene is None else scene()

    camera.scene_source = light_changes
    layout = StateLayout(tmp_path / "state")
    old = ["20260101T100000Z", "20260108T100000Z", "20260115T100000Z"]
    try:
        path = _site(tmp_path, cfg, camera.url, "keep_photos = 2\n")
        for mid in old:
            (layout.measure / mid).mkdir(parents=True)
            (layout.measure / mid / "short.dng").write_bytes(b"\0" * 4096)
            (layout.measure / f"{mid}.json").write_text(json.dumps({"measurement": mid}))
        (layout.measure / "notes").mkdir()
        report = _measure(path)
    finally:
        camera.stop()
    assert report["status"] == "failed" and "lux" in report["error"], report
    new = report["measurement"]
    assert sorted(p.name for p in layout.measure.iterdir() if p.is_dir()) == sorted(
        [old[-1], new, "notes"])
    assert (layout.measure / new / f"{next(iter(_shots(layout, new)))}").stat().st_size > 0
    assert all((layout.measure / f"{mid}.json").exists() for mid in [*old, new])
    assert layout.measure_setup.exists()


def _shots(layout: StateLayout, mid: str) -> list[str]:
    return sorted(p.name for p in (layout.measure / mid).iterdir() if p.suffix == ".dng")


def test_the_daemons_retention_pass_applies_keep_photos(tmp_path, hw):
    """The daemon's pass after every run (and at start) keeps the photos of the newest
    ``keep_photos`` measurements too: lowering it takes effect without a measurement."""
    sim, cfg = hw
    path = _site(tmp_path, cfg, "http://127.0.0.1:9", "keep_photos = 1\n")
    layout = StateLayout(tmp_path / "state")
    old = ["20260101T100000Z", "20260108T100000Z"]
    for mid in old:
        (layout.measure / mid).mkdir(parents=True)
        (layout.measure / mid / "short.dng").write_bytes(b"\0" * 4096)
    svc = Service(load_config(path), features=daemon_features())
    try:
        svc.prune()
    finally:
        svc.shutdown()
    assert sorted(p.name for p in layout.measure.iterdir() if p.is_dir()) == old[-1:]
