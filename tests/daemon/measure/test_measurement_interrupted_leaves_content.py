"""A measurement killed (kill -9) in the middle of its test patterns leaves the display showing
content with the last good tables, nothing from the half measurement kept or pushed; a
controller that loses power mid-measurement boots showing content with its last good table.

The site (controllers on ptys, lux sensor, the simulated display and the camera that photographs
it) lives in this test process; ``grassd measure --now`` runs as a real process against it."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from daemon_harness import wait_for, write_config

from grassd.daemon.core.config.settings import load_config
from grassd.daemon.core.runtime.service import Service
from grassd.daemon.core.store.history import History
from grassd.daemon.core.store.layout import StateLayout
from grassd.daemon.measure.cli import simulated_setup, start_measuring_camera
from grassd.firmware_proto.client import ControllerClient

pytestmark = pytest.mark.long

GRASSD = str(Path(sys.executable).parent / "grassd")
LEVEL = 128
#: the controllers' watchdog in these tests (s): a dead host's pattern ends this soon (and a
#: shot, 2-5 s on a loaded machine, must fit in it)
WATCHDOG_S = 10.0
MEASURE = f"""[measure]
camera = "{{url}}"
pattern_timeout_s = {WATCHDOG_S}
settle_s = 10.0
samples = 256
layouts = 1
patterns = 4
"""


@pytest.fixture
def site(tmp_path, hw):
    """The running site with a calibrated display showing level 128: (sim, config path,
    display, camera, the active run's table id, every pixel's expected position in um)."""
    sim, cfg = hw
    display, camera = start_measuring_camera(sim, cfg, None, 2500.0, samples=256)
    path = write_config(tmp_path / "grassd.toml", tmp_path / "state", cfg,
                        extra=MEASURE.format(url=camera.url))
    loaded = load_config(path)
    svc = Service(loaded)
    try:
        first = svc.one_shot()
    finally:
        svc.shutdown()
    assert first.status == "ok", first
    for c in loaded.controllers:  # content: every pixel at level 128
        with ControllerClient(c.port) as client:
            client.set_levels(c.address, np.full(16, LEVEL))
    table = np.asarray(History(StateLayout(loaded.state_dir).db).current_table().lengths_um)
    expected = np.full(32, float(table[LEVEL]))
    wait_for(lambda: np.abs(sim.positions_um() - expected).max() <= 10, 10, "level 128 shown")
    simulated_setup(loaded, display, camera.url, 2500.0)
    yield sim, path, display, camera, first.committed.table_id, expected
    camera.stop()


def _start_measuring(path: Path, tmp_path: Path) -> subprocess.Popen:
    log = (tmp_path / "measure.log").open("w")
    return subprocess.Popen([GRASSD, "measure", "--now", "--config",
                             str(path), "--json", str(tmp_path / "out.json")],
                            stdout=log, stderr=subprocess.STDOUT)


def _controllers(sim) -> list:
    return [c for bus in sim.buses for c in bus.controllers]


def _wait_for_patterns(proc: subprocess.Popen, display, tmp_path: Path) -> None:
    def alive() -> None:
        if proc.poll() is not None:
            raise AssertionError(f"grassd measure exited {proc.returncode}: "
                                 + (tmp_path / "measure.log").read_text()[-2000:])

    wait_for(lambda: display.shots >= 4, 240, "the measurement's fourth photo", check=alive,
             context=lambda: (tmp_path / "measure.log").read_text()[-2000:])


def _assert_content_with_last_tables(sim, path: Path, table_id: int, expected) -> None:
    cfg = load_config(path)
    for c in cfg.controllers:
        with ControllerClient(c.port) as client:
            assert client.read_status(c.address).table_id == table_id
    assert not StateLayout(cfg.state_dir).correction.exists()  # nothing kept from it
    runs = History(StateLayout(cfg.state_dir).db).runs(10)
    assert [r.trigger for r in runs if r.status == "ok"] == ["request"]


def test_kill_9_mid_measurement_leaves_content_with_the_last_tables(site, tmp_path):
    sim, path, display, _camera, table_id, expected = site
    proc = _start_measuring(path, tmp_path)
    try:
        _wait_for_patterns(proc, display, tmp_path)
        assert any(c.in_pattern for c in _controllers(sim))  # the display shows a pattern
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(10)
        killed_at = time.monotonic()
        wait_for(lambda: not any(c.in_pattern for c in _controllers(sim)), WATCHDOG_S + 5,
                 "the controllers' watchdog ending the pattern")
        assert time.monotonic() - killed_at <= WATCHDOG_S + 1.0
        wait_for(lambda: np.abs(sim.positions_um() - expected).max() <= 10, 10,
                 "every pixel back at level 128 of the last table")
    finally:
        if proc.poll() is None:
            proc.kill()
    _assert_content_with_last_tables(sim, path, table_id, expected)


def test_a_controller_power_cut_mid_measurement_boots_into_content(site, tmp_path):
    """A controller loses power while a photo is taken: it boots showing content through the
    last good table (the pattern lived in RAM only); its motors held the pattern's lengths,
    so the photo stands, and the measurement sends the next pattern again and finishes."""
    sim, path, display, camera, table_id, _expected = site
    victim = _controllers(sim)[0]
    last_good = victim.active_table()
    scene, seen = display.scene, {}

    def cut_during_a_photo():
        if display.shots == 4 and not seen:
            victim.power_cycle()  # its RAM (the pattern, the levels) is gone
            seen["in_pattern"] = victim.in_pattern
            seen["table"] = victim.active_table()
        return scene()

    camera.scene_source = cut_during_a_photo
    proc = _start_measuring(path, tmp_path)
    try:
        assert proc.wait(240) == 0, (tmp_path / "measure.log").read_text()[-2000:]
    finally:
        if proc.poll() is None:
            proc.kill()
    assert seen["in_pattern"] is False and np.array_equal(seen["table"], last_good)
    report = json.loads((tmp_path / "out.json").read_text())
    assert report["status"] == "ok" and report["tables"]["status"] == "ok"
    assert not any(c.in_pattern for c in _controllers(sim))  # content again, everywhere
    cfg = load_config(path)
    for c in cfg.controllers:  # the measurement's per-pixel tables, whole, on every controller
        with ControllerClient(c.port) as client:
            assert client.read_status(c.address).table_id == report["tables"]["run_id"]
    assert report["tables"]["run_id"] != table_id
