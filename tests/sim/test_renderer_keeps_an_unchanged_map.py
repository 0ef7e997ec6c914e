"""A new light whose map is the same texels (the sun moved, as the studio's time-of-day slider
moves it) keeps the uploaded map and its sampler; the traced numbers are the same bit for bit
as after a full upload."""

from __future__ import annotations

import numpy as np

from grassd.sim.lighting import build_lighting
from grassd.sim.scene import DisplaySpec, RenderSettings, Viewpoint


def test_only_the_sun_changes_and_the_numbers_do_not(renderer, shared_hdri):
    from grassd.sim.hdri import downsample, load_hdri

    img = downsample(load_hdri(shared_hdri("courtyard")), 4)
    noon = build_lighting(img, 5000.0, sun_lux=30000.0, sun_azimuth_deg=180.0,
                          sun_elevation_deg=60.0)
    evening = build_lighting(img, 5000.0, sun_lux=30000.0, sun_azimuth_deg=250.0,
                             sun_elevation_deg=15.0)
    other = build_lighting(img, 7000.0)
    display, view = DisplaySpec(rows=1, cols=1), Viewpoint(170, 2, 0)
    lengths = np.array([0.0, 10.0, 20.0])
    settings = RenderSettings(samples=256, replicates=2, seed=3)

    def trace(lighting):
        return renderer.characteristic(display, lighting, view, lengths, settings).rgb_replicates

    trace(noon)
    kept = trace(evening)  # the map of noon stays on the fields
    assert renderer._lighting is evening
    trace(other)
    fresh = trace(evening)  # uploaded in full after another map
    np.testing.assert_array_equal(kept, fresh)
    assert not np.array_equal(trace(noon), fresh)  # the sun did change the picture
