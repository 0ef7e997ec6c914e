"""A reload replaces the capture station while it is capturing: the old station finishes its
capture into a bundle (the new one starts only after it), and making the new station does not
delete the old one's work in progress. The camera is a real HTTP server on 127.0.0.1."""

from __future__ import annotations

import time

import numpy as np

from grassd.daemon.camera.config import CaptureConfig
from grassd.daemon.capture.station import CaptureLoop, Station
from grassd.daemon.core.config.settings import load_default_config
from grassd.rigs.simulated_camera import SimCamera
from grassd.rigs.simulated_site import SimLuxSensor


def small_env() -> np.ndarray:
    """A 64 x 32 sky: smooth gradient plus a bright compact sun."""
    h, w = 32, 64
    v = np.linspace(1.0, 0.2, h)[:, None, None] * np.ones((h, w, 3))
    v[5:7, 20:22] = 3000.0
    return v.astype(np.float32)


def test_replacing_the_station_mid_capture_keeps_that_capture(tmp_path):
    inbox, state = tmp_path / "inbox", tmp_path / "state"
    inbox.mkdir()
    with SimCamera(small_env(), scene_scale=1000.0, latency_s=0.03) as cam, \
            SimLuxSensor(load_default_config().light.modbus, lux=8000.0) as sensor:
        cfg = CaptureConfig(camera=cam.url, shots=5, retries=0, timeout_s=5.0,
                            command_timeout_s=5.0, interval_s=3600.0)
        old = CaptureLoop(Station(cfg, inbox, state, sensor.config)).start()
        work = state / "capture" / "work"
        t0 = time.monotonic()
        while not (work.is_dir() and any(work.rglob("shot*.jpg"))):  # mid-bracket
            assert time.monotonic() - t0 < 30, "the capture never started"
            time.sleep(0.01)
        old.stop(timeout_s=None)  # as CaptureFeature.restart on a reload
        new = CaptureLoop(Station(cfg, inbox, state, sensor.config))
        new.stop(timeout_s=None)  # only the replacement's construction matters here
        new.start(after=old)
        assert old._thread is not None
        old._thread.join(60)
        assert old.last_error is None, old.last_error
        assert old.last_bundle is not None and old.last_bundle.is_dir()
        assert sorted(p.name for p in old.last_bundle.iterdir()) == ["manifest.toml", "sky.exr"]
        new.stop()
