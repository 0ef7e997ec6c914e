"""A measurement that cannot start (the camera never set up, no camera at its address) fails
with a report saying how to fix it, and touches neither the display nor its tables."""

from __future__ import annotations

import json
from pathlib import Path

from daemon_harness import write_config

from grassd.daemon.cli.features import daemon_features
from grassd.daemon.core.config.settings import load_config
from grassd.daemon.core.runtime.service import Service
from grassd.daemon.core.store.layout import StateLayout


def _measure(tmp_path: Path, cfg, camera: str) -> dict:
    path = write_config(tmp_path / "grassd.toml", tmp_path / "state", cfg,
                        extra=f'[measure]\ncamera = "{camera}"\n')
    svc = Service(load_config(path), features=daemon_features())
    try:
        return svc.features.get("measure").now(svc)
    finally:
        svc.shutdown()


def test_a_camera_never_set_up_is_refused_with_how_to_fix(tmp_path, hw):
    sim, cfg = hw
    report = _measure(tmp_path, cfg, "http://127.0.0.1:9")
    assert report["status"] == "failed"
    assert "grassd measure setup" in report["error"]
    saved = json.loads(Path(report["report"]).read_text())
    assert saved["status"] == "failed" and saved["trigger"] == "request"
    assert not StateLayout(tmp_path / "state").correction.exists()
    assert not any(c.in_pattern for bus in sim.buses for c in bus.controllers)


def test_an_unreachable_camera_fails_the_measurement_before_any_pattern(tmp_path, hw):
    from grassd.daemon.core.store.atomic import atomic_write_json
    from grassd.daemon.measure.camera_chain import Exposure, MeasureSetup

    sim, cfg = hw
    setup = MeasureSetup((1.0, 1.0, 1.0, 1.0), 1.0, Exposure(0.01, 100, 5.6), 2500.0,
                         ((1.0, 0, 0), (0, 1.0, 0), (0, 0, 1.0)), "spydercheckr-24", "x.dng",
                         "2026-11-27T00:00:00+00:00")
    atomic_write_json(StateLayout(tmp_path / "state").measure_setup, setup.to_json())
    report = _measure(tmp_path, cfg, "http://127.0.0.1:9")  # nothing listens on port 9
    assert report["status"] == "failed" and "127.0.0.1:9" in report["error"], report
    assert not any(c.in_pattern for bus in sim.buses for c in bus.controllers)
