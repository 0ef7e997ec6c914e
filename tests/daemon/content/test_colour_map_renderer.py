"""The colour map against the renderer, not against the characteristic it was built from.

The characteristic is built as the daemon's calibration builds it (8 tuft layouts averaged,
from the reference viewpoint); the display is the default pixel (its own one layout),
rendered again with other random numbers at the levels chosen. Pictures in colours on the
display's axis are shown within 2 dE00 of the picture's colour; colours off the axis take
a level whose rendered colour is within 1 dE00 of the nearest one reachable (a grid of 32
levels rendered). docs/content.md has the figures measured."""

from __future__ import annotations

import numpy as np
import pytest

from grassd.calib.colour_spaces import lab_to_srgb
from grassd.calib.ogcd import delta_E
from grassd.daemon.content.colour_map import DisplayColours, levels_for_picture, srgb8_to_lab
from grassd.daemon.core.calibration.simulation import simulate_curve
from grassd.sim.light_input import LightInput
from grassd.sim.scene import DisplaySpec, PixelSpec, RenderSettings, Viewpoint

VIEW = Viewpoint(170.0, 2.0, 0.0)  # the reference viewpoint
TABLE_MM = np.linspace(0.0, 20.0, 256)


@pytest.fixture(scope="module")
def world(renderer, shared_hdri):
    lighting = LightInput(shared_hdri("courtyard"), 5000.0).lighting()
    built = simulate_curve(renderer, DisplaySpec(PixelSpec()), lighting, VIEW,
                           np.linspace(0.0, 20.0, 11), RenderSettings(samples=1024,
                                                                       replicates=8, seed=1),
                           layouts=8)  # as the daemon's calibration does
    colours = DisplayColours.from_curve(TABLE_MM, built.lengths_mm, built.lab, "built")

    def rendered(lengths_mm: np.ndarray) -> np.ndarray:
        """D50 Lab of the pixel at ``lengths_mm``, rendered anew (another seed, layout)."""
        xs = np.concatenate([[0.0], lengths_mm])  # the first length is the reference
        c = simulate_curve(renderer, DisplaySpec(PixelSpec()), lighting, VIEW,
                           xs, RenderSettings(samples=1024, replicates=4, seed=99))
        return c.lab[1:]

    return colours, rendered


@pytest.mark.slow
def test_on_axis_pictures_are_shown_within_2_de00(world):
    colours, rendered = world
    levels = np.arange(0, 256, 17)
    pic = np.rint(lab_to_srgb(colours.level_lab[levels]) * 255).astype(np.uint8)[None]
    chosen = levels_for_picture(pic, "nearest_de00", colours)[0]
    shown = rendered(TABLE_MM[chosen])
    de = delta_E(shown, srgb8_to_lab(pic[0]))
    print(f"on-axis: rendered vs picture dE00 max {de.max():.2f}, median {np.median(de):.2f}")
    assert de.max() <= 2.0


@pytest.mark.slow
def test_off_axis_colours_take_about_the_nearest_reachable_level(world):
    colours, rendered = world
    rng = np.random.default_rng(52)
    pic = rng.integers(0, 256, (1, 12, 3), dtype=np.uint8)
    chosen = levels_for_picture(pic, "nearest_de00", colours)[0]
    grid = np.arange(0, 256, 8)
    everything = rendered(TABLE_MM[np.concatenate([chosen, grid])])
    at_chosen, reachable = everything[:len(chosen)], everything[len(chosen):]
    want = srgb8_to_lab(pic[0])
    for i in range(len(chosen)):
        d_chosen = delta_E(at_chosen[i], want[i])
        d_best = delta_E(reachable, np.repeat(want[i:i + 1], len(grid), 0)).min()
        assert d_chosen <= d_best + 1.0, (i, d_chosen, d_best)
