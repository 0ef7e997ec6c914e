"""A scene rebuilt for another splay (the studio's slider) keeps its display's layout and the
renderer's blade fields, uploads only the grid's used part, and traces the same numbers bit for
bit as a scene built and uploaded from nothing."""

from __future__ import annotations

from dataclasses import fields, replace

import numpy as np
import pytest

from grassd.sim import geometry
from grassd.sim.lighting import build_lighting
from grassd.sim.scene import DisplaySpec, PixelSpec, RenderSettings, Viewpoint

LENGTHS = np.array([0.0, 4.0, 10.0, 20.0])


def _fresh(display: DisplaySpec, lengths: np.ndarray) -> geometry.SceneArrays:
    geometry._layouts.clear()
    return geometry.build_scene(display, lengths)


@pytest.mark.parametrize("display", [
    DisplaySpec(PixelSpec(splay_deg=7.0), rows=3, cols=3),
    DisplaySpec(rows=2, cols=2, same_layout=True),
    DisplaySpec(PixelSpec(specular=0.04, splay_deg=2.0)),
])
def test_a_kept_layout_gives_the_scene_a_fresh_one_gives(display):
    fresh = _fresh(display, LENGTHS)
    geometry.build_scene(replace(display, pixel=replace(display.pixel, splay_deg=12.0)),
                         LENGTHS[:2])
    kept = geometry.build_scene(display, LENGTHS)
    assert kept.blade_p0 is fresh.blade_p0  # the layout was kept
    for f in fields(kept):
        np.testing.assert_array_equal(np.asarray(getattr(kept, f.name)),
                                      np.asarray(getattr(fresh, f.name)), err_msg=f.name)


def test_another_splay_shares_the_layout_and_its_arrays_are_read_only():
    d = DisplaySpec(rows=3, cols=3)
    a = geometry.build_scene(d, LENGTHS)
    b = geometry.build_scene(replace(d, pixel=replace(d.pixel, splay_deg=9.0)), LENGTHS)
    assert a.blade_p0 is b.blade_p0 and a.rect_bounds is b.rect_bounds
    assert b.splay_rad > 0 and a.splay_rad == 0
    with pytest.raises(ValueError):
        a.blade_params[0, 0] = 1.0


def test_what_a_larger_scene_left_on_the_fields_changes_nothing(renderer):
    small = DisplaySpec(PixelSpec(splay_deg=5.0))
    big = DisplaySpec(PixelSpec(yellow_density=0.5), rows=3, cols=3)
    env = np.random.default_rng(3).uniform(0.2, 2.0, (32, 64, 3)).astype(np.float32)
    light = build_lighting(env, 5000.0, sun_lux=20000.0, sun_azimuth_deg=200.0,
                           sun_elevation_deg=35.0)
    s = RenderSettings(samples=256, replicates=2, seed=11)
    vp = Viewpoint(170, 2, 20)

    def run(display, index=0):
        m = renderer.characteristic(display, light, vp, LENGTHS, s, pixel_index=index)
        return m.rgb_replicates, m.paths_traced, m.rays_traced

    first = run(small)
    run(big, 4)  # more blades, rectangles, cells and items than ``small``
    renderer._uploaded = None  # the blades too are uploaded again, over the big scene's
    again = run(small)
    np.testing.assert_array_equal(first[0], again[0])
    assert first[1:] == again[1:]
    # another splay of the same display: the blades stay, the grid is uploaded again
    run(replace(small, pixel=replace(small.pixel, splay_deg=1.0)))
    assert renderer._uploaded is not None
    back = run(small)
    np.testing.assert_array_equal(first[0], back[0])


def test_smaller_launches_change_no_number(renderer):
    """The studio lowers the fewest paths a launch takes so that it can stop a run between
    launches."""
    env = np.random.default_rng(5).uniform(0.2, 2.0, (32, 64, 3)).astype(np.float32)
    light = build_lighting(env, 5000.0)
    display = DisplaySpec(PixelSpec(splay_deg=4.0))
    s = RenderSettings(samples=256, replicates=4, seed=2)
    calls = []
    one = renderer.characteristic(display, light, Viewpoint(150, 3, -10), LENGTHS, s)
    try:
        renderer.launch_paths(256)  # one replicate a launch
        split = renderer.characteristic(display, light, Viewpoint(150, 3, -10), LENGTHS, s,
                                        progress=lambda done, n: calls.append(done))
    finally:
        renderer.launch_paths()
    assert len(calls) == 4
    np.testing.assert_array_equal(one.rgb_replicates, split.rgb_replicates)
    assert (one.paths_traced, one.rays_traced) == (split.paths_traced, split.rays_traced)


def test_a_replicate_split_across_launches_keeps_its_paths(renderer):
    """With a cap on the paths a launch takes, a larger replicate goes in launches of consecutive
    shares of its paths (the studio's larger replicates): the same paths, traced the same
    way, their sums added (float64 rounding)."""
    env = np.random.default_rng(6).uniform(0.2, 2.0, (32, 64, 3)).astype(np.float32)
    light = build_lighting(env, 5000.0)
    s = RenderSettings(samples=1000, replicates=2, seed=4)  # 32 x 32 = 1024 paths
    one = renderer.characteristic(DisplaySpec(), light, Viewpoint(150, 3, -10), LENGTHS, s)
    calls = []
    try:
        renderer.launch_paths(most=300)  # 4 shares of 256 paths a replicate
        split = renderer.characteristic(DisplaySpec(), light, Viewpoint(150, 3, -10), LENGTHS,
                                        s, progress=lambda done, n: calls.append(done))
    finally:
        renderer.launch_paths()
    assert len(calls) == 8 and calls[-1] == len(LENGTHS)
    np.testing.assert_allclose(split.rgb_replicates, one.rgb_replicates, rtol=1e-12, atol=0)
    assert not np.allclose(one.rgb_replicates[0], one.rgb_replicates[1], rtol=1e-3)
    assert (one.paths_traced, one.rays_traced) == (split.paths_traced, split.rays_traced)
