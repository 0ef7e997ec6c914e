"""A global table's characteristic averages random tuft layouts: replicate j traces layout
j mod ``layouts`` with its own seed, and ``[simulation] layouts`` sets how many."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from grassd.calib.ogcd import ogcd_from_samples
from grassd.daemon.core.calibration.simulation import layout_seed, simulate_curve, white_radiance
from grassd.daemon.core.config.settings import parse_config
from grassd.daemon.core.errors import ConfigError
from grassd.sim.light_input import LightInput
from grassd.sim.scene import DisplaySpec, PixelSpec, RenderSettings, Viewpoint

LENGTHS = np.array([0.0, 5.0, 10.0, 20.0])
VIEW = Viewpoint(170.0, 2.0, 0.0)


@pytest.fixture(scope="module")
def lighting(shared_hdri):
    return LightInput(shared_hdri("courtyard"), 5000.0).lighting()


def test_replicates_cycle_through_the_layouts(renderer, lighting):
    settings = RenderSettings(samples=256, replicates=6, seed=3)
    display = DisplaySpec(PixelSpec(layout_seed=5))
    curve = simulate_curve(renderer, display, lighting, VIEW, LENGTHS, settings, layouts=3)
    parts = []
    for k in range(3):  # replicates 0 and 3 trace layout 5, 1 and 4 layout 6, 2 and 5 layout 7
        shown = replace(display, pixel=replace(display.pixel, layout_seed=5 + k))
        m = renderer.characteristic(shown, lighting, VIEW, LENGTHS, replace(
            settings, replicates=2, seed=layout_seed(3, k)))
        parts.append(m.rgb_replicates)
    by_layout = np.concatenate(parts)
    assert np.allclose(curve.rgb_linear, by_layout.mean(axis=0), rtol=1e-12)
    expected = ogcd_from_samples(by_layout / white_radiance(lighting), space="rec709")
    assert np.allclose(curve.ogcd, expected.ogcd, rtol=1e-9)
    one = simulate_curve(renderer, display, lighting, VIEW, LENGTHS, settings)
    own = renderer.characteristic(display, lighting, VIEW, LENGTHS, settings)
    assert np.array_equal(one.rgb_linear, own.rgb_linear)  # layouts = 1: one launch as before
    assert not np.allclose(one.rgb_linear, curve.rgb_linear)


def test_adaptive_rounds_continue_the_layout_cycle(renderer, lighting):
    """Later rounds of an adaptive run take the next layouts in turn (a round of one
    replicate traces one layout)."""
    settings = RenderSettings(samples=64, replicates=2, seed=1)
    curve = simulate_curve(renderer, DisplaySpec(PixelSpec()), lighting, VIEW, LENGTHS,
                           settings, layouts=3, target_stderr=1e-4, max_replicates=5)
    assert curve.replicates == 5 and np.isfinite(curve.ogcd).all()


def test_config_reads_layouts_with_its_default_and_bounds():
    from importlib.resources import files

    default = files("grassd.daemon.core.config").joinpath("default.toml").read_text()
    assert parse_config(default).simulation.layouts == 8

    def with_layouts(n: int):
        return parse_config(default.replace("[simulation]\n", f"[simulation]\nlayouts = {n}\n"))

    assert with_layouts(1).simulation.layouts == 1
    with pytest.raises(ConfigError, match="layouts"):
        with_layouts(0)
    assert with_layouts(64).simulation.layouts == 64  # more than the replicates: each its own
