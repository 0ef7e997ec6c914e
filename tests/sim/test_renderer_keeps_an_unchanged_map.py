"""A new light of the same map (the sun moved, as the studio's time-of-day slider moves it, or
another lux, as its lux field sets it) keeps the uploaded map and its sampler: the map is
uploaded unscaled and scaled in the kernel. The traced numbers are the same bit for bit as
after a full upload, whatever ran before."""

from __future__ import annotations

import numpy as np
import pytest

from grassd.sim.lighting import build_lighting
from grassd.sim.scene import DisplaySpec, RenderSettings, Viewpoint

LENGTHS = np.array([0.0, 10.0, 20.0])


@pytest.fixture(scope="module")
def img(shared_hdri):
    from grassd.sim.hdri import downsample, load_hdri

    return downsample(load_hdri(shared_hdri("courtyard")), 4)


@pytest.fixture
def trace(renderer, monkeypatch):
    """Trace a light; ``trace.uploads`` counts the maps uploaded (each builds a sampler)."""
    display, view = DisplaySpec(rows=1, cols=1), Viewpoint(170, 2, 0)
    settings = RenderSettings(samples=256, replicates=2, seed=3)
    upload = renderer._upload_env
    uploads = []

    def counted(env):
        uploads.append(env.shape)
        return upload(env)

    monkeypatch.setattr(renderer, "_upload_env", counted)

    def run(lighting):
        return renderer.characteristic(display, lighting, view, LENGTHS,
                                       settings).rgb_replicates

    run.uploads = uploads
    return run


def test_only_the_sun_changes_and_the_numbers_do_not(renderer, img, trace):
    noon = build_lighting(img, 5000.0, sun_lux=30000.0, sun_azimuth_deg=180.0,
                          sun_elevation_deg=60.0)
    evening = build_lighting(img, 5000.0, sun_lux=30000.0, sun_azimuth_deg=250.0,
                             sun_elevation_deg=15.0)
    other = build_lighting(img, 5000.0, rotation_deg=90.0)  # another map
    trace(noon)
    n = len(trace.uploads)
    kept = trace(evening)  # the map of noon stays on the fields
    assert renderer._lighting is evening and len(trace.uploads) == n
    trace(other)
    fresh = trace(evening)  # uploaded in full after another map
    assert len(trace.uploads) == n + 2
    np.testing.assert_array_equal(kept, fresh)
    assert not np.array_equal(trace(noon), fresh)  # the sun did change the picture


def test_another_lux_keeps_the_map_and_scales_the_light(img, trace):
    dim, bright = build_lighting(img, 5000.0), build_lighting(img, 7000.0)
    other = build_lighting(img, 5000.0, rotation_deg=90.0)
    trace(dim)
    n = len(trace.uploads)
    kept = trace(bright)  # the map of the dim light, scaled in the kernel
    assert len(trace.uploads) == n
    trace(other)
    fresh = trace(bright)
    assert len(trace.uploads) == n + 2
    np.testing.assert_array_equal(kept, fresh)
    # the same paths at 7/5 of the light: every radiance scales with the map
    np.testing.assert_allclose(kept, trace(dim) * (7000.0 / 5000.0), rtol=1e-5)
