"""Config keys for whole-display tables ([tables]) and audience regions ([audience])."""

from __future__ import annotations

import re

import pytest

from grassd.daemon.core.config.settings import (
    AudienceConfig,
    TablesConfig,
    default_config_text,
    parse_config,
)
from grassd.daemon.core.errors import ConfigError


def _cfg(extra: str):
    return parse_config(default_config_text() + "\n" + extra, source="grassd.toml")


def test_defaults_keep_one_global_table_and_no_region():
    cfg = _cfg("")
    assert cfg.tables == TablesConfig() and cfg.tables.granularity == "global"
    assert cfg.audience is None


def test_tables_and_audience_are_read():
    cfg = _cfg("""
[tables]
granularity = "controller"
eye = "pixel"
group_tolerance_deg = 0.5
check_groups = -1

[audience]
polygon = [[-2, -3], [2, -3], [2, -1], [-2, -1]]
h_cm = [150, 185]
objective = "worst"
ground_samples = 24
""")
    assert cfg.tables == TablesConfig("controller", "pixel", 0.5, 0.1, -1)
    assert cfg.audience == AudienceConfig(polygon=((-2.0, -3.0), (2.0, -3.0), (2.0, -1.0),
                                                   (-2.0, -1.0)),
                                          h_cm=(150.0, 185.0), ground_samples=24,
                                          height_samples=2, objective="worst")
    from grassd.daemon.core.calibration.audience import AudienceRegion

    region = AudienceRegion(cfg.audience.polygon, cfg.audience.h_cm)
    assert region.area_m2 == pytest.approx(8.0)


@pytest.mark.parametrize("granularity, layout, shared", [
    ("pixel", None, True), ("controller", None, False), ("global", None, False),
    ("pixel", "per_pixel", False), ("controller", "shared", True), ("global", "auto", False),
])
def test_layout_is_shared_for_pixel_tables_unless_configured(granularity, layout, shared):
    """[tables] layout: "auto" (default) traces one tuft layout for every pixel when the tables
    are per pixel (they must not be fitted to a random draw), each pixel's own otherwise."""
    from grassd.daemon.core.calibration.display_model import display_spec_for_config

    extra = f'[tables]\ngranularity = "{granularity}"\n'
    if layout is not None:
        extra += f'layout = "{layout}"\n'
    cfg = _cfg(extra)
    assert cfg.tables.layout == (layout or "auto")
    spec = display_spec_for_config(cfg)
    assert spec.same_layout is shared
    assert (spec.rows, spec.cols, spec.pitch_mm) == (cfg.display.rows, cfg.display.cols,
                                                     cfg.display.pitch_mm)


@pytest.mark.parametrize("extra, key, message", [
    ('[tables]\ngranularity = "row"', "tables.granularity", "must be one of"),
    ("[tables]\ngroup_tolerance_deg = -1.0", "tables.group_tolerance_deg", "between"),
    ("[tables]\nsize = 3", "tables.size", "unknown key"),
    ('[tables]\nlayout = "mixed"', "tables.layout", "must be one of"),
    ("[audience]\npolygon = [[0, 0], [1, 0]]\nh_cm = [150, 180]", "audience.polygon",
     "at least 3"),
    ("[audience]\npolygon = [[0, 0], [1, 0], [2, 0]]\nh_cm = [150, 180]", "audience.polygon",
     "no area"),
    ("[audience]\npolygon = [[0, 0], [1, 0], [1, 1]]\nh_cm = [190, 150]", "audience.h_cm",
     "low <= high"),
    ("[audience]\npolygon = [[0, 0], [1, 0], [1, 1]]", "audience.h_cm", "required"),
    ('[audience]\npolygon = [[0, 0], [1, 0], [1, 1]]\nh_cm = [150, 180]\nobjective = "max"',
     "audience.objective", "must be one of"),
])
def test_bad_values_name_key_and_line(extra, key, message):
    with pytest.raises(ConfigError, match=message) as info:
        _cfg(extra)
    assert info.value.key == key
    assert info.value.line is not None and info.value.line > 60  # in the appended text


def test_config_drives_whole_display_tables(renderer):
    """[display] 2x2, two weighted viewpoints, [tables] per controller -> two tables."""
    import numpy as np

    from grassd.daemon.core.calibration.display_model import (
        display_tables_for_config,
        simulate_display,
    )
    from grassd.sim.lighting import build_lighting
    from grassd.sim.scene import DisplaySpec, RenderSettings, Viewpoint

    text = re.sub(r"(?m)^rows = 4\b", "rows = 2",
                  re.sub(r"(?m)^cols = 8\b", "cols = 2", default_config_text()))
    text = text.replace('pixels = "0-15"', 'pixels = "0-1"').replace(
        'pixels = "16-31"', 'pixels = "2-3"')
    cfg = parse_config(text + '\n[tables]\ngranularity = "controller"\ncheck_groups = 0\n')
    env = np.ones((32, 64, 3), np.float32)
    env[:16] *= 2.0
    lighting = build_lighting(env, 10000.0)
    settings = RenderSettings(samples=256, replicates=4, seed=2)
    lengths = np.array([0.0, 10.0, 20.0])
    calls = []
    tables, sims = display_tables_for_config(renderer, cfg, lighting, lengths, settings,
                                             progress=lambda d, n: calls.append((d, n)))
    assert len(sims) == 2 and calls[-1][0] == calls[-1][1]
    assert tables.granularity == "controller" and len(tables.tables) == 2
    assert tables.names == [c.name for c in cfg.controllers]
    assert tables.unit_of_pixel.tolist() == [0, 0, 1, 1]
    # the combined characteristic is the weighted mean of the two viewers' (weights 1, 0.5)
    display = DisplaySpec(rows=2, cols=2)
    a = simulate_display(renderer, display, lighting, Viewpoint(170, 2, 0), lengths, settings,
                         check_groups=0)
    b = simulate_display(renderer, display, lighting, Viewpoint(160, 2, 30), lengths, settings,
                         check_groups=0)
    np.testing.assert_array_equal(a.pixel_ogcd(), sims[0].pixel_ogcd())
    want = (1.0 * a.pixel_ogcd() + 0.5 * b.pixel_ogcd()) / 1.5
    from grassd.daemon.core.calibration.display_model import combine_viewpoints

    np.testing.assert_allclose(combine_viewpoints(sims, [1.0, 0.5]).pixel_ogcd(), want,
                               rtol=1e-12)


@pytest.mark.parametrize("layout, shared", [(None, False), ("shared", True),
                                            ("per_pixel", False)])
def test_global_run_patch_follows_the_layout_setting(layout, shared):
    """The one-table run (granularity "global", no [audience]) simulates a patch of up to 3 x 3
    pixels: [tables] layout applies to it as to every other run, not silently ignored."""
    from grassd.daemon.core.calibration.calibrate import Calibrator

    extra = "[tables]\n" + (f'layout = "{layout}"\n' if layout else "")
    cfg = _cfg(extra)
    spec, centre = Calibrator(cfg).display()
    assert spec.same_layout is shared
    assert (spec.rows, spec.cols, spec.pitch_mm) == (min(cfg.display.rows, 3),
                                                     min(cfg.display.cols, 3),
                                                     cfg.display.pitch_mm)
    assert centre == (spec.rows // 2) * spec.cols + spec.cols // 2
