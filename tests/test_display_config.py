"""Config keys for whole-display tables ([tables]) and audience regions ([audience])."""

from __future__ import annotations

import pytest

from grassd.daemon.config import (
    AudienceConfig,
    TablesConfig,
    default_config_text,
    parse_config,
)
from grassd.daemon.errors import ConfigError


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
    from grassd.daemon.audience import AudienceRegion

    region = AudienceRegion(cfg.audience.polygon, cfg.audience.h_cm)
    assert region.area_m2 == pytest.approx(8.0)


@pytest.mark.parametrize("extra, key, message", [
    ('[tables]\ngranularity = "row"', "tables.granularity", "must be one of"),
    ("[tables]\ngroup_tolerance_deg = -1.0", "tables.group_tolerance_deg", "between"),
    ("[tables]\nsize = 3", "tables.size", "unknown key"),
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
