"""A studio condition parsed from JSON: defaults, the sun's modes and a message per bad value."""

from __future__ import annotations

import pytest

from grassd.daemon.studio.inputs import StudioInputError, default_lengths, parse_condition


def _parse(**data):
    return parse_condition(data, green_max_mm=20.0, timezone="Asia/Tokyo",
                           lights={"file", "upload:1"}, default_light="file")


def test_a_condition_takes_the_defaults_it_is_not_given():
    c = _parse(ambient_lux=5000, viewpoint=[170, 2, 0])
    assert (c.light, c.tables, c.image, c.splay_deg, c.length_mm) == ("file", "live", None,
                                                                      None, 10.0)
    assert c.lengths_mm == default_lengths(20.0) == tuple(float(x) for x in range(0, 21, 2))
    assert c.sun.mode == "none" and c.target_stderr == 0.1
    assert default_lengths(19.0)[-1] == 19.0


def test_the_sun_as_a_manifest_names_it_by_site_time_or_as_measured():
    c = _parse(ambient_lux=5000, viewpoint=[170, 2, 0], sun_lux=30000, sun_azimuth_deg=200,
               sun_elevation_deg=35)
    assert (c.sun.mode, c.sun.lux, c.sun.azimuth_deg, c.sun.elevation_deg) == (
        "direction", 30000.0, 200.0, 35.0)
    c = _parse(ambient_lux=5000, viewpoint=[170, 2, 0],
               sun={"mode": "site", "lux": 40000, "when": "2026-11-27T15:00"})
    assert c.sun.when.utcoffset().total_seconds() == 9 * 3600  # the site's zone
    assert _parse(ambient_lux=1, viewpoint=[170, 2, 0], sun={"mode": "measured"}).sun.mode == \
        "measured"
    assert _parse(ambient_lux=1, viewpoint=[170, 2, 0], sun_lux=0).sun.mode == "none"


@pytest.mark.parametrize(("data", "words"), [
    ([], "send a JSON object"),
    ({"viewpoint": [170, 2, 0]}, "ambient_lux is required"),
    ({"ambient_lux": float("nan"), "viewpoint": [170, 2, 0]}, "must be a number"),
    ({"ambient_lux": True, "viewpoint": [170, 2, 0]}, "must be a number"),
    ({"ambient_lux": 5, "viewpoint": [0, 2, 0]}, "behind the display"),
    ({"ambient_lux": 5, "viewpoint": [170, 0, 0]}, "distance must be in (0, 1000]"),
    ({"ambient_lux": 5, "viewpoint": "170,2,0"}, "[h_cm, d_m, theta_deg]"),
    ({"ambient_lux": 5, "viewpoint": [170, 2, 0], "lengths_mm": [3]}, "2 to 64 lengths"),
    ({"ambient_lux": 5, "viewpoint": [170, 2, 0], "splay_deg": 80}, "splay_deg = 80"),
    ({"ambient_lux": 5, "viewpoint": [170, 2, 0], "tables": "old"}, "\"live\" or \"active\""),
    ({"ambient_lux": 5, "viewpoint": [170, 2, 0], "light": "x"}, "file, upload:1"),
    ({"ambient_lux": 5, "viewpoint": [170, 2, 0], "sun": {"mode": "moon"}}, "sun mode 'moon'"),
    ({"ambient_lux": 5, "viewpoint": [170, 2, 0],
      "sun": {"mode": "site", "lux": 1, "when": "teatime"}}, "not an ISO 8601 time"),
    ({"ambient_lux": 5, "viewpoint": [170, 2, 0], "sun_lux": 5, "sun_azimuth_deg": 3},
     "give both sun_azimuth_deg and sun_elevation_deg"),
])
def test_each_bad_value_is_named(data, words):
    with pytest.raises(StudioInputError) as err:
        parse_condition(data, green_max_mm=20.0, timezone="UTC", lights={"file", "upload:1"},
                        default_light="file")
    assert words in str(err.value)
