"""Per-pixel viewing geometry of a whole display and grouping of pixels (numpy only)."""

from __future__ import annotations

import numpy as np
import pytest

from grassd.daemon.core.calibration.display_model import (
    DisplaySimulationError,
    geometry_from_eye,
    group_pixels,
    neighbour_mask,
    pixel_geometry,
)
from grassd.sim.scene import DisplaySpec, Viewpoint


def test_world_eye_is_one_point_seen_from_each_pixel():
    display = DisplaySpec(rows=8, cols=8)
    viewer = Viewpoint(170, 2.0, 25.0)
    geo = pixel_geometry(display, viewer, eye="world")
    world_eye = viewer.eye_m((0.0, 0.0))
    # every pixel's own viewpoint puts the eye back at the same world point
    eyes = np.stack([geo.viewpoint(i).eye_m(tuple(c)) for i, c in enumerate(geo.centres_m)])
    np.testing.assert_allclose(eyes, np.broadcast_to(world_eye, eyes.shape), atol=1e-12)
    # ... so the pixels see it from different directions (8 x 33.5 mm at 2 m: several degrees)
    assert np.ptp(geo.theta_deg) > 5.0
    assert np.ptp(geo.elevation_deg) > 2.0
    # directions are unit vectors pointing at the eye
    rel = world_eye - np.column_stack([geo.centres_m, np.zeros(64)])
    np.testing.assert_allclose(geo.directions, rel / np.linalg.norm(rel, axis=1)[:, None],
                               atol=1e-12)


def test_pixel_mode_keeps_the_relative_viewpoint():
    geo = pixel_geometry(DisplaySpec(rows=3, cols=3), Viewpoint(160, 3.0, -40.0), eye="pixel")
    assert set(geo.theta_deg) == {-40.0} and set(geo.d_m) == {3.0} and set(geo.h_cm) == {160.0}
    with pytest.raises(DisplaySimulationError, match="eye must be one of"):
        pixel_geometry(DisplaySpec(), Viewpoint(), eye="nowhere")


def test_eye_below_the_display_is_rejected_and_straight_above_is_clamped():
    with pytest.raises(DisplaySimulationError, match="above the display plane"):
        geometry_from_eye(DisplaySpec(), np.array([0.0, -1.0, -0.1]))
    geo = geometry_from_eye(DisplaySpec(), np.array([0.0, 0.0, 1.0]))
    assert geo.d_m[0] > 0 and np.isfinite(geo.theta_deg[0])


def test_neighbour_masks():
    m = neighbour_mask(3, 3).reshape(3, 3)
    assert m[1, 1] == 15  # interior: all four
    assert m[0, 0] == 2 | 8 and m[2, 2] == 1 | 4
    assert neighbour_mask(1, 1).tolist() == [0]


@pytest.mark.parametrize("tol", [0.25, 0.5, 1.0, 2.0])
def test_groups_respect_the_tolerance(tol):
    display = DisplaySpec(rows=16, cols=16)
    geo = pixel_geometry(display, Viewpoint(165, 1.5, 35.0))
    groups = group_pixels(geo, tol, by_neighbours=False)
    elev = geo.elevation_deg
    for g in range(groups.n_groups):
        members = groups.members(g)
        assert np.ptp(elev[members]) < tol
        assert groups.labels[groups.representatives[g]] == g
        assert groups.labels[groups.farthest[g]] == g
    # the reported spread is the largest angle to the representative
    dirs = geo.directions
    ang = np.degrees(np.arccos(np.clip(np.einsum(
        "ij,ij->i", dirs, dirs[groups.representatives[groups.labels]]), -1, 1)))
    worst = np.zeros(groups.n_groups)
    np.maximum.at(worst, groups.labels, ang)
    np.testing.assert_allclose(groups.spread_deg, worst, atol=1e-9)
    assert groups.sizes.sum() == 256


def test_group_count_falls_with_tolerance_and_neighbours_split_groups():
    geo = pixel_geometry(DisplaySpec(rows=16, cols=16), Viewpoint(170, 3.0, 10.0))
    counts = [group_pixels(geo, t, by_neighbours=False).n_groups for t in (0.0, 0.3, 1.0, 3.0)]
    assert counts[0] == 256
    assert counts == sorted(counts, reverse=True) and counts[-1] < counts[1] < 256
    plain = group_pixels(geo, 3.0, by_neighbours=False)
    split = group_pixels(geo, 3.0, by_neighbours=True)
    assert split.n_groups > plain.n_groups
    masks = geo.neighbours
    for g in range(split.n_groups):  # never a border pixel grouped with an interior one
        assert len(set(masks[split.members(g)])) == 1


def test_bad_tolerances():
    geo = pixel_geometry(DisplaySpec(rows=2, cols=2), Viewpoint())
    with pytest.raises(DisplaySimulationError, match="tolerance"):
        group_pixels(geo, -1.0)
    with pytest.raises(DisplaySimulationError, match="distance tolerance"):
        group_pixels(geo, 1.0, distance_tolerance=0.0)


@pytest.mark.parametrize("rows, cols", [(8, 8), (9, 9), (20, 24)])
def test_capacity_holds_the_whole_display(rows, cols):
    from grassd.daemon.core.calibration.display_model import capacity_for
    from grassd.sim.geometry import build_scene

    sc = build_scene(DisplaySpec(rows=rows, cols=cols), np.array([0.0, 20.0]))
    cap = capacity_for(rows * cols)
    assert sc.n_blades <= cap.blades and sc.n_rects <= cap.rects
    assert len(sc.cell_items) <= cap.items
    assert sc.grid_shape[0] * sc.grid_shape[1] <= cap.cells
