"""A slanted eye sees the pixel in front through a pixel's quad, the more the longer the grass
(:mod:`grassd.daemon.measure.neighbours`), and a fit that knows it recovers each pixel's own
gains where a fit of each pixel alone pulls them towards its neighbours'
(:func:`grassd.daemon.measure.pixel_model.fit_variation`)."""

from __future__ import annotations

import numpy as np
import pytest

from grassd.daemon.core.calibration.variation import DisplayVariation
from grassd.daemon.measure.neighbours import (
    OFFSETS,
    OWN,
    NeighbourShares,
    neighbour_index,
    record_neighbour_shares,
)
from grassd.daemon.measure.pixel_model import GREEN, PixelColourModel, fit_variation, lab_of
from grassd.sim.albedo_terms import monomials
from grassd.sim.lighting import build_lighting
from grassd.sim.scene import DisplaySpec, PixelSpec, Viewpoint

FRONT, BEHIND = OFFSETS.index((-1, 0)), OFFSETS.index((1, 0))
COLUMN = DisplaySpec(PixelSpec(), rows=3, cols=1)
LENGTHS = np.array([1.0, 10.0, 20.0])
SKY = build_lighting(np.ones((16, 32, 3), np.float32), ambient_lux=1000.0)


def _shares(renderer, viewpoint: Viewpoint) -> np.ndarray:
    """(2, 3, G, 9) the column's shares, every pixel seen from ``viewpoint``."""
    got = record_neighbour_shares(renderer, COLUMN, SKY, [viewpoint] * 3, LENGTHS)
    np.testing.assert_allclose(got.shares.sum(axis=-1), 1.0, atol=1e-9)
    return got.shares


def test_the_pixel_in_front_shows_through_a_slanted_quad_as_the_grass_grows(renderer):
    """Seen at 45 degrees along the column, the middle pixel's quad is its own grass at 1 mm
    and partly the front pixel's at 20 mm; the pixel behind barely shows."""
    green = _shares(renderer, Viewpoint(40.0, 0.4, 0.0))[GREEN, 1]  # (G, 9)
    assert green[0, OWN] > 0.9
    assert green[0, FRONT] < green[1, FRONT] < green[2, FRONT]
    assert green[2, FRONT] > 0.15
    assert green[2, BEHIND] < 0.05


def test_a_steeper_eye_sees_less_of_the_front_pixel(renderer):
    """From high above, less of the quad is hidden by the pixel in front than at 45 deg."""
    slanted = _shares(renderer, Viewpoint(40.0, 0.4, 0.0))[GREEN, 1, -1, FRONT]
    steep = _shares(renderer, Viewpoint(300.0, 0.4, 0.0))[GREEN, 1, -1, FRONT]
    assert steep < 0.5 * slanted


def test_neighbours_outside_the_display_have_no_index():
    """A corner pixel of a 2 x 2 display has three neighbours and itself."""
    index = neighbour_index(DisplaySpec(PixelSpec(), rows=2, cols=2))
    assert sorted(index[0][index[0] >= 0].tolist()) == [0, 1, 2, 3]
    assert index[3, OFFSETS.index((-1, -1))] == 0


# ---------------------------------------------------------------- a fit that knows the mixing
ROWS, COLS = 3, 4
GRID = np.linspace(0.0, 20.0, 5)


def _linear_model(neighbours: NeighbourShares | None) -> PixelColourModel:
    """A display whose colour is linear in the yellow and green albedos: the yellow's term
    falls and the green's grows with the length, over a constant base."""
    rows = [tuple(m) for m in monomials(3)]
    n, g = ROWS * COLS, len(GRID)
    coefficients = np.zeros((n, g, len(rows), 3))
    coefficients[:, :, rows.index((0, 0, 1, 0, 0))] = 0.3
    coefficients[:, :, rows.index((1, 0, 0, 0, 0))] = (1.0 - GRID / 25.0)[:, None]
    coefficients[:, :, rows.index((0, 1, 0, 0, 0))] = (0.2 + GRID / 20.0)[:, None]
    albedo = np.array([[0.5, 0.45, 0.1], [0.08, 0.3, 0.06], [0.2, 0.15, 0.1], [0.05] * 3])
    return PixelColourModel(GRID, coefficients, np.ones(3), albedo, neighbours=neighbours)


def _front_mixing() -> NeighbourShares:
    """Every pixel's quad shows the pixel in front up to a third at the longest grass."""
    n = ROWS * COLS
    mixed = NeighbourShares.none(n, len(GRID))
    index = neighbour_index(DisplaySpec(PixelSpec(), rows=ROWS, cols=COLS))
    has_front = index[:, FRONT] >= 0
    front = np.where(has_front[:, None], GRID[None, :] / 60.0, 0.0)  # (N, G)
    for m in range(2):
        mixed.shares[m, :, :, FRONT] = front
        mixed.shares[m, :, :, OWN] = 1.0 - front
    return NeighbourShares(mixed.shares, index)


@pytest.mark.parametrize("seed", [0, 1])
def test_a_fit_that_knows_the_neighbours_recovers_each_pixels_own_gains(seed):
    """Photos made with the pixel in front mixed in: the fit with the same mixing finds the
    true gains; each pixel fitted alone misses them by several times more."""
    rng = np.random.default_rng(seed)
    n = ROWS * COLS
    truth = DisplayVariation(rng.uniform(-1.0, 1.0, n), rng.uniform(0.8, 1.25, n),
                             rng.uniform(0.8, 1.25, n))
    for g in (truth.green_gain, truth.yellow_gain):
        g /= np.exp(np.mean(np.log(g)))
    mixing = _front_mixing()
    cmd = np.tile(np.linspace(0.0, 20.0, 9), (n, 1))
    photos = lab_of(_linear_model(mixing).rgb(cmd, truth))
    knowing = fit_variation(_linear_model(mixing), cmd, photos).variation
    alone = fit_variation(_linear_model(None), cmd, photos).variation
    miss_knowing = np.abs(knowing.green_gain - truth.green_gain).max()
    miss_alone = np.abs(alone.green_gain - truth.green_gain).max()
    assert miss_knowing < 0.01
    assert miss_alone > 3 * miss_knowing


def test_gains_read_by_powers_match_the_clipped_reading():
    """Where no albedo clips, the model reads a variation from its terms gathered by the
    gains' powers; a gain that clips one pixel's green sends the reading through the
    clipped albedos, and the other pixels read the same either way."""
    model = _linear_model(None)
    n = ROWS * COLS
    v = DisplayVariation(np.zeros(n), np.linspace(0.8, 1.2, n), np.linspace(1.1, 0.9, n))
    fast = model.grid_radiance(v)
    v.green_gain[0] = 4.0  # 0.3 x 4 > 1: clips
    clipped = model.grid_radiance(v)
    np.testing.assert_allclose(clipped[1:], fast[1:], rtol=1e-12)
    assert not np.allclose(clipped[0], fast[0])
