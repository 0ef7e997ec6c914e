"""Reuse across green lengths when the green blades splay (``renderer.Renderer.radiance``): a
green blade's plane turns with its length, so a ray that comes near one (or is blocked by one)
is traced again at the next length; rays that stay clear of every green blade, and the light
samples and bounces of a vertex that stays, keep their answers. The radiance must be what
tracing each length on its own gives."""

# (no "from __future__ import annotations": Taichi reads kernel annotations as objects)


import numpy as np
import pytest

from grassd.sim.lighting import build_lighting
from grassd.sim.scene import DisplaySpec, PixelSpec, RenderSettings, Viewpoint

SUN = dict(sun_lux=30000.0, sun_azimuth_deg=40.0, sun_elevation_deg=25.0)

# (panorama, splay deg, specular, sun, viewpoint (h cm, d m, theta deg), lengths)
CASES = [
    ("courtyard", 8.0, 0.0, False, (170, 2, 5), np.linspace(0.0, 20.0, 11)),
    ("forest", 3.0, 0.3, True, (120, 3, -20), np.linspace(0.0, 20.0, 21)),
    ("city", 8.0, 0.3, False, (165, 2, 20), np.array([0.0, 12.0, 3.0, 20.0, 7.25, 12.0, 1.0,
                                                      16.5, 19.0, 5.0, 9.0])),
    ("courtyard", 3.0, 0.0, True, (150, 1.5, 60), np.linspace(0.0, 20.0, 21)),
]


@pytest.mark.parametrize("hdri, splay, specular, sun, view, lengths", CASES,
                         ids=["courtyard-8-lambert", "forest-3-glossy-sun", "city-8-glossy",
                              "courtyard-3-lambert-sun"])
def test_splayed_paths_reused_across_lengths_equal_each_length_traced_alone(
        renderer, shared_hdri, hdri, splay, specular, sun, view, lengths):
    """Every (length, replicate) mean equals the same length traced on its own, to float
    rounding (a kept light sample's contribution is read back; measured equal bit for bit on
    these cases), while tracing fewer rays than tracing every length in full.

    A length on its own is traced as [x, x], so that it runs the same compiled kernel (the
    one-length kernel rounds hit points differently: see
    test_sim_render.test_one_path_for_all_lengths_equals_tracing_each_length_alone). A bound
    that keeps a path's answer 1 mm past where it may change fails here (tried by hand:
    differences up to ~1e-2 relative)."""
    lighting = build_lighting(shared_hdri(hdri), ambient_lux=5000, **(SUN if sun else {}))
    display = DisplaySpec(pixel=PixelSpec(splay_deg=splay, specular=specular))
    s = RenderSettings(samples=256, replicates=2, seed=13)
    vp = Viewpoint(*view)
    many = renderer.characteristic(display, lighting, vp, lengths, s)
    alone = np.stack([renderer.characteristic(display, lighting, vp, [x, x], s)
                      .rgb_replicates[:, 0] for x in lengths], axis=1)
    np.testing.assert_allclose(many.rgb_replicates, alone, rtol=1e-6, atol=0)
    assert np.all(many.rgb_replicates > 0)
    full = sum(renderer.characteristic(display, lighting, vp, [x], s).rays_traced
               for x in lengths)  # every length in full (one-length kernel: counts to a flip)
    assert many.paths_traced <= len(lengths) * many.samples_per_length
    assert many.rays_traced < 0.9 * full
