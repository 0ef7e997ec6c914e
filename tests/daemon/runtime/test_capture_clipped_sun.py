"""A sun still clipped in the shortest exposure is flagged in the bundle, and the daemon then
restores it from the lux reading (sun_from_hdri) instead of trusting the clipped map."""

from __future__ import annotations

from dataclasses import replace
from datetime import UTC, datetime

import numpy as np
import pytest

from grassd.daemon.camera.config import CaptureConfig
from grassd.daemon.capture.station import Station
from grassd.daemon.core.calibration.calibrate import Calibrator
from grassd.daemon.core.config.settings import load_default_config
from grassd.daemon.core.store.manifest import parse_manifest
from grassd.rigs.simulated_camera import SimCamera
from grassd.sim.hdri import load_hdri
from grassd.sim.lighting import uv_to_direction


def sky(sun: float) -> np.ndarray:
    """256 x 128 sky (gradient) with a 2 x 2 texel sun (1.2e-3 sr) of radiance ``sun`` at
    rows 20-21, columns 80-81 (elevation 58.6 deg)."""
    h, w = 128, 256
    v = np.linspace(0.3, 0.1, h)[:, None, None] * np.ones((h, w, 3))
    v[20:22, 80:82] = sun
    return v.astype(np.float32)


def capture(tmp_path, sun: float):
    with SimCamera(sky(sun), scene_scale=1000.0, latency_s=0.01) as cam:
        st = Station(CaptureConfig(camera=cam.url, shots=7, retries=0), tmp_path / "inbox",
                     tmp_path / "state")
        st.client.poll_s = 0.01
        return st.capture(lux=60000.0)


@pytest.mark.parametrize(("sun", "clipped"), [(1e6, True), (20.0, False)])
def test_clipped_sun_is_flagged(tmp_path, sun, clipped):
    out = capture(tmp_path, sun)
    assert out.manifest["capture"]["sun_clipped"] is clipped


def test_daemon_restores_a_flagged_sun_from_lux(tmp_path):
    import tomllib

    out = capture(tmp_path, 1e6)
    m = parse_manifest(tomllib.loads((out.bundle / "manifest.toml").read_text()), out.bundle)
    assert m.light.sun_from_hdri
    cal = Calibrator(load_default_config())
    light = replace(m.light, timestamp=datetime.now(UTC))
    lighting = cal.lighting(light)
    assert lighting.sun_direction is not None and lighting.sun_lux > 0  # restored from lux
    expected = uv_to_direction(np.array([81.0 / 256]), np.array([21.0 / 128]))[0]
    angle = np.degrees(np.arccos(np.clip(lighting.sun_direction @ expected, -1, 1)))
    assert angle < 2.0
    assert lighting.ambient_lux + lighting.sun_lux == pytest.approx(60000.0, rel=1e-3)
    plain = cal.lighting(replace(light, sun_from_hdri=False))
    assert plain.sun_direction is None  # unflagged: the clipped map alone, no sun added
    assert load_hdri(m.light.hdri).shape == (128, 256, 3)
