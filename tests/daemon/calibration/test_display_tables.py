"""Whole-display simulation with the real renderer: neighbours, grouping error, tables."""

from __future__ import annotations

import json

import numpy as np
import pytest

from grassd.daemon.core.calibration.display_model import (
    DisplaySimulationError,
    DisplayTables,
    build_display_tables,
    controller_pixels,
    errors_on,
    mean_characteristic,
    simulate_display,
    table_deviation,
)
from grassd.daemon.core.calibration.simulation import simulate_curve

LENGTHS = np.array([0.0, 10.0, 20.0])


@pytest.fixture(scope="module")
def lighting():
    from grassd.sim.lighting import build_lighting

    env = np.ones((32, 64, 3), np.float32)
    env[:16] *= 2.0  # brighter sky than ground
    return build_lighting(env, 10000.0, sun_lux=40000.0, sun_azimuth_deg=200.0,
                          sun_elevation_deg=35.0)


@pytest.fixture(scope="module")
def settings():
    from grassd.sim.scene import RenderSettings

    return RenderSettings(samples=256, replicates=4, seed=3)


def test_neighbours_change_an_oblique_view(renderer, lighting):
    """At a low view a pixel's neighbours fill what a lone pixel shows of the surroundings."""
    from grassd.sim.scene import DisplaySpec, RenderSettings, Viewpoint

    s = RenderSettings(samples=1024, replicates=4, seed=3)
    vp = Viewpoint(60, 2.0, 0.0)
    lone = simulate_curve(renderer, DisplaySpec(rows=1, cols=1), lighting, vp, LENGTHS, s)
    inner = simulate_curve(renderer, DisplaySpec(rows=3, cols=3), lighting, vp, LENGTHS, s,
                           pixel_index=4)
    diff = np.abs(inner.ogcd - lone.ogcd)[-1]
    se = np.hypot(inner.ogcd_stderr, lone.ogcd_stderr)[-1]
    assert diff > 10 * se and diff > 3.0, (lone.ogcd, inner.ogcd, se)


def test_shared_layout_leaves_pixels_differing_by_position_only(renderer, lighting):
    """Both ends of a 1 x 3 row seen from the same relative viewpoint: with their own random
    tufts they differ by several dE00 (layout noise a per-pixel table must not be fitted to);
    with one shared layout only their mirrored neighbours differ (measured 1.2 vs 3.7)."""
    from grassd.sim.scene import DisplaySpec, RenderSettings, Viewpoint

    s = RenderSettings(samples=1024, replicates=4, seed=3)
    lengths = np.array([0.0, 5.0, 10.0, 15.0, 20.0])
    diff = {}
    for same in (True, False):
        d = DisplaySpec(rows=1, cols=3, same_layout=same)
        a, b = (simulate_curve(renderer, d, lighting, Viewpoint(170, 2.0, 0.0), lengths, s,
                               pixel_index=i) for i in (0, 2))
        diff[same] = np.abs(a.ogcd - b.ogcd).max()
        se = np.hypot(a.ogcd_stderr, b.ogcd_stderr).max()
    assert diff[False] > 5 * se and diff[True] < 0.5 * diff[False], diff


@pytest.fixture(scope="module")
def per_pixel(renderer, lighting, settings):
    from grassd.sim.scene import DisplaySpec, Viewpoint

    calls = []
    sim = simulate_display(renderer, DisplaySpec(rows=3, cols=3), lighting,
                           Viewpoint(120, 0.6, 30.0), LENGTHS, settings, tolerance_deg=0.0,
                           progress=lambda d, n: calls.append((d, n)))
    return sim, calls


def test_per_pixel_simulation_traces_every_pixel_from_its_own_direction(per_pixel):
    sim, calls = per_pixel
    assert sim.groups.n_groups == 9 and len(sim.curves) == 9
    assert calls[-1] == (9, 9) and sim.grouping_error is None
    # each curve was traced from the pixel's own viewpoint (a fixed eye 0.6 m away)
    thetas = [c.theta_deg for c in sim.curves]
    np.testing.assert_allclose(thetas, sim.geometry.theta_deg[sim.groups.representatives])
    assert np.ptp(thetas) > 4.0
    ogcd = sim.pixel_ogcd()
    assert ogcd.shape == (9, 3) and np.all(ogcd[:, 0] == 0)
    assert sim.pixel_stderr().shape == (9, 3)
    # pixels differ (direction, neighbours, their own tuft layout) by more than the noise
    spread = np.ptp(ogcd[:, -1])
    assert spread > 4 * sim.pixel_stderr()[:, -1].max()


def test_tables_per_pixel_controller_global(per_pixel):
    from grassd.calib.characteristic import Characteristic, fit_characteristic

    sim, _ = per_pixel
    px = build_display_tables(sim, "pixel")
    assert len(px.tables) == 9 and px.pixel_lengths_um.shape == (9, 256)
    assert px.pixel_lengths_um.dtype == np.uint16
    assert np.all(np.diff(px.pixel_lengths_um.astype(int), axis=1) >= 0)
    assert px.pixel_error.max() < 0.05  # own table: only micrometre rounding remains
    glob = build_display_tables(sim, "global")
    assert len(glob.tables) == 1 and np.all(glob.pixel_lengths_um == glob.tables[0].lengths_um)
    assert glob.pixel_error.max() > 10 * px.pixel_error.max()
    ctrl = build_display_tables(sim, "controller", controllers=[np.arange(0, 5)],
                                controller_names=["bus#1"])
    assert ctrl.names == ["bus#1", "global (pixels without a controller)"]
    assert ctrl.unit_of_pixel.tolist() == [0] * 5 + [1] * 4
    # a controller table is made for its pixels: it fits their mean characteristic (what it is
    # built from) to rounding, better than the global table made for all nine does
    fit5 = fit_characteristic(mean_characteristic(sim, np.arange(5)))
    own = np.abs(table_deviation(fit5, ctrl.tables[0].lengths_mm)).max()
    other = np.abs(table_deviation(fit5, glob.tables[0].lengths_mm)).max()
    assert own < 0.05 and own < other, (own, other)
    # the reported error is the deviation of the pixel's characteristic under its table

    c = sim.curves[sim.groups.labels[7]]
    fit = fit_characteristic(Characteristic(c.lengths_mm, c.ogcd,
                                            np.maximum(c.ogcd_stderr, 1e-6)))
    want = np.abs(table_deviation(fit, glob.pixel_lengths_um[7] / 1000.0)).max()
    assert glob.pixel_error[7] == pytest.approx(want)
    with pytest.raises(DisplaySimulationError, match="granularity"):
        build_display_tables(sim, "row")
    with pytest.raises(DisplaySimulationError, match="pixel sets"):
        build_display_tables(sim, "controller")
    with pytest.raises(DisplaySimulationError, match="shares pixels"):
        build_display_tables(sim, "controller", controllers=[np.arange(3), np.arange(2, 4)])


def test_controller_pixels_from_config_ranges():
    from grassd.daemon.core.config.settings import ControllerConfig

    cs = [ControllerConfig("/dev/a", 115200, 1, pixels=((0, 3), (8, 8))),
          ControllerConfig("/dev/a", 115200, 2, pixels=((4, 7),))]
    got = controller_pixels(cs, 9)
    assert [g.tolist() for g in got] == [[0, 1, 2, 3, 8], [4, 5, 6, 7]]
    with pytest.raises(DisplaySimulationError, match="display has 6"):
        controller_pixels(cs, 6)


def test_grouping_cuts_traces_and_reports_its_error(renderer, lighting, settings, per_pixel):
    from grassd.sim.scene import DisplaySpec, Viewpoint

    exact, _ = per_pixel
    sim = simulate_display(renderer, DisplaySpec(rows=3, cols=3), lighting,
                           Viewpoint(120, 0.6, 30.0), LENGTHS, settings, tolerance_deg=15.0,
                           by_neighbours=False, check_groups=-1)
    assert sim.groups.n_groups < 9
    err = sim.grouping_error
    assert err is not None and len(err.groups) >= 1
    # the checked member really is traced: its curve equals the per-pixel run's (same seed)
    for g, p, d in zip(err.groups, err.pixels, err.max_ogcd_diff, strict=True):
        rep = sim.groups.representatives[g]
        want = np.abs(exact.curves[p].ogcd - exact.curves[rep].ogcd).max()
        assert d == pytest.approx(want, abs=1e-9)
    assert np.all(err.table_error >= err.own_table_error - 1e-9)
    # decomposition: the member from the representative's direction was traced too, so
    # member-vs-representative splits into a geometry part and a pixel (tufts, position) part
    assert np.all(np.isfinite(err.geometry_diff)) and np.all(np.isfinite(err.pixel_diff))
    assert np.all(err.max_ogcd_diff <= err.geometry_diff + err.pixel_diff + 1e-9)
    assert np.all(err.geometry_diff > 0) and np.all(err.pixel_diff > 0)
    assert sim.seconds["trace"] > 0
    summary = err.summary()
    assert summary["groups_checked"] == len(err.groups)
    assert summary["max_ogcd_diff"] == pytest.approx(err.max_ogcd_diff.max())
    assert summary["max_pixel_diff"] == pytest.approx(err.pixel_diff.max())
    plain = simulate_display(renderer, DisplaySpec(rows=3, cols=3), lighting,
                             Viewpoint(120, 0.6, 30.0), LENGTHS, settings, tolerance_deg=15.0,
                             by_neighbours=False, check_groups=1, decompose=False)
    assert len(plain.grouping_error.groups) == 1
    assert np.isnan(plain.grouping_error.geometry_diff).all()


def test_errors_on_a_per_pixel_run_measure_what_grouping_adds(renderer, lighting, settings,
                                                               per_pixel):
    """errors_on(per-pixel run, tables): every pixel's error on its own characteristic. Its
    own tables give the tables' own pixel_error; grouped tables give the same for the traced
    representatives (same seed, same trace) and at least as much for the other members."""
    from grassd.sim.scene import DisplaySpec, Viewpoint

    exact, _ = per_pixel
    own = build_display_tables(exact, "pixel")
    np.testing.assert_allclose(errors_on(exact, own), own.pixel_error, atol=1e-12)
    grouped = simulate_display(renderer, DisplaySpec(rows=3, cols=3), lighting,
                               Viewpoint(120, 0.6, 30.0), LENGTHS, settings, tolerance_deg=15.0,
                               by_neighbours=False, check_groups=0)
    assert grouped.groups.n_groups < 9
    err = errors_on(exact, build_display_tables(grouped, "pixel"))
    reps = grouped.groups.representatives
    np.testing.assert_allclose(err[reps], own.pixel_error[reps], atol=1e-9)
    members = np.setdiff1d(np.arange(9), reps)
    assert np.all(err[members] >= own.pixel_error[members] - 1e-9)
    assert err[members].max() > own.pixel_error[members].max() + 0.05
    with pytest.raises(DisplaySimulationError, match="reference has 9 pixels"):
        errors_on(exact, DisplayTables("pixel", [], [], np.zeros(4, np.int64),
                                       np.zeros((4, 256)), np.zeros(4), np.zeros(4)))


def test_grouping_checks_skip_the_decomposition_with_a_shared_layout(renderer, lighting,
                                                                     settings):
    """The pixel part of a grouping error is a layout difference: with one shared layout the
    check traces the member once (no second trace from the representative's direction)."""
    from grassd.sim.scene import DisplaySpec, Viewpoint

    calls = []
    sim = simulate_display(renderer, DisplaySpec(rows=3, cols=3, same_layout=True), lighting,
                           Viewpoint(120, 0.6, 30.0), LENGTHS, settings, tolerance_deg=15.0,
                           by_neighbours=False, check_groups=1,
                           progress=lambda d, n: calls.append(n))
    err = sim.grouping_error
    assert len(err.groups) == 1 and np.isnan(err.geometry_diff).all()
    assert "max_pixel_diff" not in err.summary() and "max_geometry_diff" not in err.summary()
    json.dumps(err.summary(), allow_nan=False)  # reports stay strict JSON
    assert calls[-1] == sim.groups.n_groups + 1
