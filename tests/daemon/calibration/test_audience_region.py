"""Audience regions: sampling and the mean/worst region table."""

from __future__ import annotations

import numpy as np
import pytest

from grassd.calib.characteristic import fit_characteristic
from grassd.calib.length_table import build_length_table
from grassd.daemon.core.calibration.audience import (
    AudienceError,
    AudienceRegion,
    centre_pixel,
    evaluate_table,
    points_in_polygon,
    region_table,
    simulate_region,
)
from grassd.daemon.core.calibration.display_model import curve_characteristic

LENGTHS = np.array([0.0, 5.0, 10.0, 15.0, 20.0])
#: An L-shaped walkway south and east of the display (m).
L_SHAPE = np.array([[-2.0, -3.0], [2.5, -3.0], [2.5, 1.0], [1.5, 1.0], [1.5, -1.5],
                    [-2.0, -1.5]])


def test_polygon_membership_and_area():
    region = AudienceRegion(L_SHAPE, (150, 180))
    assert region.area_m2 == pytest.approx(4.5 * 1.5 + 1.0 * 2.5)
    inside = points_in_polygon(np.array([[0.0, -2.0], [2.0, 0.0], [0.0, 0.0], [-3, -2]]),
                               L_SHAPE)
    assert inside.tolist() == [True, True, False, False]


def test_sampling_covers_the_region_and_the_heights():
    region = AudienceRegion(L_SHAPE, (150, 180))
    s = region.sample(n_ground=20, n_heights=3)
    assert np.all(points_in_polygon(s.ground_xy, L_SHAPE))
    assert 10 <= len(s.ground_xy) <= 30
    assert s.n == 3 * len(s.ground_xy)
    assert sorted(set(np.round(s.eyes_m[:, 2] * 100, 6))) == [150.0, 165.0, 180.0]
    np.testing.assert_allclose(s.eyes_m[:, :2], s.ground_xy[s.ground])
    cells = s.cell_of_ground
    np.testing.assert_allclose(s.ground_xy, np.column_stack([s.grid_x[cells[:, 1]],
                                                             s.grid_y[cells[:, 0]]]))
    one = region.sample(n_ground=1, n_heights=1)
    assert 1 <= one.n <= 3 and np.all(one.eyes_m[:, 2] == pytest.approx(1.65))
    tiny = AudienceRegion(np.array([[0.0, -2.0], [0.02, -2.0], [0.02, -1.99]]), (160, 160))
    assert tiny.sample(n_ground=50).n >= 1  # a sliver still gets a viewpoint


@pytest.mark.parametrize("poly, h, match", [
    ([[0, 0], [1, 0]], (150, 180), "at least 3"),
    ([[0, 0], [1, 0], [2, 0]], (150, 180), "no area"),
    ([[0, 0], [1, 0], [1, 1]], (180, 150), "eye heights"),
    ([[0, 0], [1, np.nan], [1, 1]], (150, 180), "finite"),
])
def test_bad_regions(poly, h, match):
    with pytest.raises(AudienceError, match=match):
        AudienceRegion(np.array(poly, float), h)


@pytest.fixture(scope="module")
def region_fits(renderer):
    from grassd.sim.lighting import build_lighting
    from grassd.sim.scene import DisplaySpec, RenderSettings

    env = np.ones((32, 64, 3), np.float32)
    env[:16] *= 2.0
    lighting = build_lighting(env, 10000.0, sun_lux=40000.0, sun_azimuth_deg=200.0,
                              sun_elevation_deg=35.0)
    display = DisplaySpec(rows=3, cols=3)
    region = AudienceRegion(L_SHAPE, (150, 180))
    samples = region.sample(n_ground=8, n_heights=2)
    curves = simulate_region(renderer, display, lighting, samples, LENGTHS,
                             RenderSettings(samples=256, replicates=4, seed=5))
    return region, samples, display, curves, [fit_characteristic(curve_characteristic(c))
                                              for c in curves]


def test_each_viewpoint_sees_the_centre_pixel_from_its_own_direction(region_fits):
    _region, samples, display, curves, _fits = region_fits
    assert len(curves) == samples.n and centre_pixel(display) == 4
    for eye, c in zip(samples.eyes_m, curves, strict=True):
        from grassd.sim.scene import Viewpoint

        back = Viewpoint(c.h_cm, c.d_m, c.theta_deg).eye_m((0.0, 0.0))  # pixel 4 at origin
        np.testing.assert_allclose(back, eye, atol=1e-9)
    # the region really spans different characteristics
    ranges = np.array([c.ogcd[-1] for c in curves])
    assert np.ptp(ranges) > 2.0


def test_worst_table_beats_every_single_viewpoint_table_on_the_worst_error(region_fits):
    _r, _s, _d, _c, fits = region_fits
    worst = region_table(fits, "worst")
    mean = region_table(fits, "mean")
    singles = [evaluate_table(fits, build_length_table(f).lengths_um) for f in fits]
    best_single_worst = min(t.max_error.max() for t in singles)
    best_single_mean = min(t.mean_error.mean() for t in singles)
    # exact per-level optimisation on a 1 um grid (tolerance: grid step x steepest slope)
    assert worst.max_error.max() <= best_single_worst + 1e-3
    assert mean.mean_error.mean() <= best_single_mean + 1e-3
    assert worst.max_error.max() <= mean.max_error.max() + 1e-3
    assert mean.mean_error.mean() <= worst.mean_error.mean() + 1e-3
    for t in (worst, mean):
        assert t.lengths_um[0] == 0 and t.lengths_um[-1] == 20000
        assert np.all(np.diff(t.lengths_um.astype(int)) >= 0)
        assert t.deviation.shape == (len(fits), 256)
    # a single viewpoint's region table is its own ordinary table, up to micrometre rounding
    solo = region_table(fits[:1], "worst")
    assert np.abs(solo.lengths_um.astype(int) - build_length_table(fits[0]).lengths_um).max() <= 2


def test_weights_pull_the_mean_table_towards_a_viewpoint(region_fits):
    _r, _s, _d, _c, fits = region_fits
    even = region_table(fits, "mean")
    w = np.ones(len(fits))
    w[0] = 1000.0
    pulled = region_table(fits, "mean", weights=w)
    assert pulled.mean_error[0] <= even.mean_error[0] + 1e-9
    with pytest.raises(AudienceError, match="objective"):
        region_table(fits, "median")
    with pytest.raises(AudienceError, match="weights"):
        region_table(fits, "mean", weights=np.zeros(len(fits)))
