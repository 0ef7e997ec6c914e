"""grassd.sim.light_input: one light measurement, and the Lighting it builds."""

from __future__ import annotations

import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from grassd.sim.errors import HdriError, LightingError
from grassd.sim.hdri import write_exr
from grassd.sim.light_input import LightInput
from grassd.sim.lighting import build_lighting


@pytest.fixture(scope="module")
def sky(tmp_path_factory) -> Path:
    """A real EXR panorama, brighter towards the zenith and warmer on one side."""
    env = np.ones((16, 32, 3), np.float32)
    env[:8] *= np.linspace(3.0, 1.0, 8, dtype=np.float32)[:, None, None]
    env[:, :8, 0] *= 1.5
    path = tmp_path_factory.mktemp("hdri") / "sky.exr"
    write_exr(path, env)
    return path


def test_lighting_is_build_lighting_of_the_same_readings(sky):
    light = LightInput(sky, 8000.0, sun_lux=30000.0, sun_azimuth_deg=200.0,
                       sun_elevation_deg=40.0, rotation_deg=30.0, flip=True)
    got = light.lighting()
    want = build_lighting(sky, 8000.0, sun_lux=30000.0, sun_azimuth_deg=200.0,
                          sun_elevation_deg=40.0, rotation_deg=30.0, flip=True)
    assert np.array_equal(got.env, want.env)
    assert np.array_equal(got.sun_direction, want.sun_direction)
    assert np.array_equal(got.sun_irradiance_rgb, want.sun_irradiance_rgb)
    assert (got.rotation_deg, got.flipped) == (30.0, True)
    assert got.total_lux == pytest.approx(38000.0, rel=1e-5)


def test_an_already_loaded_map_replaces_the_file(sky):
    from grassd.sim.hdri import load_hdri

    light = LightInput(sky, 500.0)
    assert np.array_equal(light.lighting(load_hdri(sky)).env, light.lighting().env)
    gone = replace(light, hdri=sky.parent / "gone.exr")  # never read when the map is given
    assert np.array_equal(gone.lighting(load_hdri(sky)).env, light.lighting().env)
    with pytest.raises(HdriError, match="gone.exr"):
        gone.lighting()


def test_impossible_readings_are_refused_by_lighting(sky):
    with pytest.raises(LightingError, match="ambient lux"):
        LightInput(sky, -5.0).lighting()
    with pytest.raises(LightingError, match="without a sun direction"):
        LightInput(sky, 500.0, sun_lux=1000.0).lighting()


def test_importing_it_loads_neither_numpy_nor_taichi():
    """The daemon's manifest parser holds a LightInput; the type alone costs nothing."""
    out = subprocess.run(
        [sys.executable, "-c", "import sys, grassd.sim.light_input; "
         "print('numpy' in sys.modules, 'taichi' in sys.modules)"],
        capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["False", "False"]
