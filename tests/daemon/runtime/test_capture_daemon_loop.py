"""The whole loop with nobody in between: `grassd run` (a subprocess) with a [capture] section
captures from a simulated OSC camera on 127.0.0.1, reads the simulated Modbus sensor, drops
bundles into its own inbox, calibrates and pushes to simulated controllers on ptys. Two
captures under two different lights make two different tables."""

from __future__ import annotations

import subprocess
import time
from pathlib import Path

import numpy as np
import pytest
from daemon_harness import wait_for as harness_wait_for
from prometheus_client.parser import text_string_to_metric_families
from test_grassd_run_end_to_end import GRASSD
from test_grassd_run_end_to_end import config_text as e2e_config_text

from grassd.daemon.core.config.settings import load_default_config
from grassd.daemon.core.runtime.control import request
from grassd.daemon.core.store.history import History
from grassd.firmware_proto.tables import table_crc
from grassd.rigs.processes import end_process
from grassd.rigs.simulated_camera import SimCamera
from grassd.rigs.simulated_site import SimulatedHardware
from grassd.sim.hdri import default_site_hdri, downsample, load_hdri


def _loop(svc):
    """The service's capture loop now (None: none)."""
    return svc.features.get("capture").loop


def config_text(state: Path, cfg, camera_url: str) -> str:
    """The end-to-end tests' configuration plus a capture station photographing ``camera_url``
    every 10 s."""
    return e2e_config_text(state, cfg, extra=f"""[capture]
camera = "{camera_url}"
interval_s = 10
shots = 7
retry_s = 1
""")


def wait_for(cond, timeout: float, what: str, proc, log: Path):
    """:func:`daemon_harness.wait_for`, failing at once if the daemon process exits."""

    def alive() -> None:
        if proc.poll() is not None:
            raise AssertionError(f"daemon exited while waiting for {what}:\n"
                                 f"{log.read_text()[-3000:]}")

    return harness_wait_for(cond, timeout, what, check=alive,
                            context=lambda: log.read_text()[-3000:])


def captures(state: Path) -> list[str]:
    names = []
    for d in ("inbox", "processing", "archive", "rejected"):
        if (state / d).is_dir():
            names += [p.name for p in (state / d).iterdir() if "capture-" in p.name
                      and not p.name.startswith(".")]
    return names


def ok_runs(state: Path) -> list:
    if not (state / "state.db").exists():
        return []
    with History(state / "state.db") as h:
        return [r for r in reversed(h.runs(20)) if r.status == "ok"]


@pytest.mark.slow
def test_daemon_captures_under_two_lights_and_makes_two_tables(tmp_path):
    env = load_hdri(default_site_hdri())
    env = downsample(env, env.shape[1] // 256) if env.shape[1] > 256 else env
    # the second light: brighter (the sensor reads 12000 lx) and warmer
    later = env * np.array([1.0, 0.9, 0.75], np.float32)
    hw = SimulatedHardware(load_default_config(), tmp_path / "hw", lux=4000.0)
    cfg = hw.start()
    cam = SimCamera(env, scene_scale=1000.0).start()
    state = tmp_path / "state"
    config = tmp_path / "grassd.toml"
    config.write_text(config_text(state, cfg, cam.url))
    log = tmp_path / "daemon.log"
    started = time.time()
    proc = subprocess.Popen([GRASSD, "run", "--config", str(config), "--tick", "0.2"],
                            stdout=open(log, "ab"), stderr=subprocess.STDOUT)
    try:
        wait_for(lambda: captures(state), 120, "the first capture", proc, log)
        cam.set_scene(env=later, scene_scale=3000.0)  # the light changes before the next one
        assert hw.sensor is not None
        hw.sensor.lux = 12000.0
        runs = wait_for(lambda: (r := ok_runs(state)) and len(r) >= 2 and r, 180,
                        "two calibrations from two captures", proc, log)
        first, second = runs[0], runs[1]
        assert (first.lux, second.lux) == (4000.0, 12000.0)  # the sensor, read at capture
        assert first.table_crc != second.table_crc  # two lights, two tables

        def pushed() -> bool:  # the latest table reaches both controllers (pushes follow commits)
            active = {table_crc(dev.active_table()) for bus in hw.buses
                      for dev in bus.controllers}
            return active == {ok_runs(state)[-1].table_crc}

        wait_for(pushed, 60, "the latest table on both controllers", proc, log)
        cap = request(state / "control.sock", {"cmd": "status"}, timeout_s=30)["status"]
        assert cap["capture"]["camera"] == cam.url and cap["capture"]["captures"] >= 2
        # the operator's metrics say when the station last delivered a bundle
        prom = Path(cap["metrics_textfile"]).read_text()
        [delivered] = [f.samples[0].value for f in text_string_to_metric_families(prom)
                       if f.name == "grassd_capture_last_success_timestamp_seconds"]
        assert started < delivered <= cap["capture"]["last_success_at"]
        archived = sorted(p.name for p in (state / "archive").iterdir())
        assert len([a for a in archived if "capture-" in a]) >= 2
        assert not [p for p in (state / "inbox").iterdir() if p.name.startswith(".")]
        print(f"\nruns {first.id} ({first.lux:g} lx, crc {first.table_crc:#010x}) and "
              f"{second.id} ({second.lux:g} lx, crc {second.table_crc:#010x})")
    finally:
        end_process(proc, 30)
        cam.stop()
        hw.stop()


def test_reload_starts_and_stops_the_capture_station(tmp_path, hw):
    """SIGHUP (Service.reload) with a new [capture] section starts the station's thread, a
    reload without it stops it; a calibration is never waited for."""
    import daemon_harness

    _, cfg = hw
    env = load_hdri(default_site_hdri())
    env = downsample(env, env.shape[1] // 128) if env.shape[1] > 128 else env
    path = daemon_harness.write_config(tmp_path / "g.toml", tmp_path / "state", cfg)
    svc = daemon_harness.service(path)
    try:
        assert _loop(svc) is None
        with SimCamera(env, scene_scale=1000.0, latency_s=0.01) as cam:
            daemon_harness.write_config(path, tmp_path / "state", cfg, extra=(
                f'[capture]\ncamera = "{cam.url}"\ninterval_s = 3600\nshots = 5\n'))
            assert svc.reload() is True and _loop(svc) is not None
            wait_for(lambda: _loop(svc).last_bundle is not None
                     or _loop(svc).last_error, 60, "a capture", _Alive(), path)
            assert _loop(svc).last_error is None
            assert svc.status().to_json()["capture"]["captures"] == 1
            loop = _loop(svc)
            daemon_harness.write_config(path, tmp_path / "state", cfg)
            assert svc.reload() is True and _loop(svc) is None
            loop._thread.join(10)
            assert not loop._thread.is_alive()
        daemon_harness.tick_until(svc, lambda: svc.history.current_table() is not None, 60)
    finally:
        svc.shutdown()


class _Alive:
    """A stand-in process for :func:`wait_for` that never exits."""

    def poll(self) -> None:
        return None
