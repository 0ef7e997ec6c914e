"""A studio condition parsed from JSON: defaults, the sun's modes and a message per bad value."""

from __future__ import annotations

import pytest

from grassd.daemon.studio.inputs import (
    CONDITION_KEYS,
    MAX_SHOWN_CHARS,
    StudioInputError,
    default_lengths,
    parse_condition,
)

EYE = {"ambient_lux": 5000, "viewpoint": [170, 2, 0]}


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
    ({"ambient_lux": 5, "viewpoint": [1e300, 2, 0]}, "at most 1 km (0 < h <= 100000 cm)"),
    ({"ambient_lux": 5, "viewpoint": "170,2,0"}, "[h_cm, d_m, theta_deg]"),
    ({"ambient_lux": 5, "viewpoint": [170, 2, 0], "lengths_mm": [3]}, "2 to 64 lengths"),
    ({"ambient_lux": 5, "viewpoint": [170, 2, 0], "splay_deg": 80}, "splay_deg = 80"),
    ({"ambient_lux": 5, "viewpoint": [170, 2, 0], "tables": "old"}, "\"live\" or \"active\""),
    ({"ambient_lux": 5, "viewpoint": [170, 2, 0], "light": "x"}, "file, upload:1"),
    ({"ambient_lux": 5, "viewpoint": [170, 2, 0], "sun": {"mode": "moon"}}, "sun mode 'moon'"),
    ({"ambient_lux": 5, "viewpoint": [170, 2, 0],
      "sun": {"mode": "site", "lux": 1, "when": "teatime"}}, "not an ISO 8601 time"),
    ({"ambient_lux": 5, "viewpoint": [170, 2, 0], "sun_lux": 5, "sun_azimuth_deg": 3},
     "sun_lux and sun_azimuth_deg need sun_elevation_deg"),
])
def test_each_bad_value_is_named(data, words):
    with pytest.raises(StudioInputError) as err:
        parse_condition(data, green_max_mm=20.0, timezone="UTC", lights={"file", "upload:1"},
                        default_light="file")
    assert words in str(err.value)


def _refused(**data) -> str:
    with pytest.raises(StudioInputError) as err:
        _parse(**data)
    return str(err.value)


@pytest.mark.parametrize("lengths", [[0, 0], [0, 4, 4, 4], [8, 4, 0], [4, 2, 6]])
def test_lengths_must_increase_strictly_from_the_reference(lengths):
    words = _refused(**EYE, lengths_mm=lengths)
    assert words == ("lengths_mm must increase strictly (the first is the reference, the "
                     f"shortest grass); got {lengths!r}")
    assert _parse(**EYE, lengths_mm=[2, 3, 20]).lengths_mm == (2.0, 3.0, 20.0)
    assert "2 to 64 lengths" in _refused(**EYE, lengths_mm=[0])
    assert "2 to 64 lengths" in _refused(**EYE, lengths_mm=list(range(65)))
    assert "outside 0..20 mm" in _refused(**EYE, lengths_mm=[0, 21])


def test_a_null_means_the_same_as_the_key_left_out():
    optional = ("light", "sun", "sun_lux", "sun_azimuth_deg", "sun_elevation_deg",
                "splay_deg", "length_mm", "lengths_mm", "tables", "image", "target_stderr",
                "pixel")
    assert set(optional) | {"ambient_lux", "viewpoint"} == set(CONDITION_KEYS)
    assert _parse(**EYE, **dict.fromkeys(optional)) == _parse(**EYE)
    assert _parse(**EYE, target_stderr=None).target_stderr == 0.1
    assert _parse(**EYE, light=None).light == "file"
    c = _parse(**EYE, sun={"mode": "site", "lux": 40000, "when": "2026-11-27T15:00",
                           "azimuth_deg": None})
    assert c.sun.mode == "site"
    # required ones stay required
    assert _refused(ambient_lux=None, viewpoint=[170, 2, 0]) == "ambient_lux is required (lx)"
    assert "viewpoint is required" in _refused(ambient_lux=5000, viewpoint=None)


def test_unknown_keys_are_refused_naming_them_and_the_known_ones():
    words = _refused(**EYE, lenghts_mm=[0, 20])
    assert words.startswith("unknown key 'lenghts_mm' in the condition: it takes light, ")
    assert all(k in words for k in CONDITION_KEYS)
    assert "unknown keys 'id', 'picture'" in _refused(**EYE, id=3, picture="p1")
    assert "unknown key 'lux'" in _refused(**EYE, lux=5000)
    # what the page sends (studio.js condition(), also pinned as B) is all known
    page = {"light": "file", "ambient_lux": 5000, "viewpoint": [170, 2, 0], "splay_deg": None,
            "length_mm": 10, "tables": "live", "pixel": None, "image": "p1"}
    for sun in ({"mode": "none"}, {"mode": "measured"},
                {"mode": "site", "lux": 40000, "when": "2026-11-27T15:00"}):
        assert _parse(**page, sun=sun).sun.mode == sun["mode"]
    assert "sun mode none does not take 'lux'" in _refused(**EYE, sun={"mode": "none",
                                                                          "lux": 5})


@pytest.mark.parametrize(("given", "words"), [
    ({"sun_elevation_deg": 35}, "sun_elevation_deg needs sun_lux and sun_azimuth_deg"),
    ({"sun_azimuth_deg": 200}, "sun_azimuth_deg needs sun_lux and sun_elevation_deg"),
    ({"sun_lux": 30000}, "sun_lux needs sun_azimuth_deg and sun_elevation_deg"),
    ({"sun_azimuth_deg": 200, "sun_elevation_deg": 35}, "need sun_lux:"),
    ({"sun_lux": 0, "sun_elevation_deg": 35}, "sun_lux and sun_elevation_deg need "
                                               "sun_azimuth_deg"),
])
def test_a_manifest_sun_given_in_part_is_refused_naming_what_is_missing(given, words):
    assert words in _refused(**EYE, **given)


def test_sun_values_given_are_checked_even_at_zero_lux():
    assert "sun_azimuth_deg must be a number (deg), got 'x'" in _refused(
        **EYE, sun_lux=0, sun_azimuth_deg="x", sun_elevation_deg=10)
    assert "need sun_elevation_deg" in _refused(**EYE, sun_lux=0, sun_azimuth_deg="x")
    assert "elevation_deg must be a number" in _refused(**EYE, sun={
        "mode": "direction", "lux": 0, "azimuth_deg": 10, "elevation_deg": "high"})
    assert "sun time 'teatime'" in _refused(**EYE, sun={"mode": "site", "lux": 0,
                                                        "when": "teatime"})
    # a reading without sun may have been taken with the sun down (a bundle manifest's range)
    assert _parse(**EYE, sun_lux=0, sun_azimuth_deg=10, sun_elevation_deg=-5).sun.mode == "none"


def test_the_sun_is_given_as_an_object_or_as_manifest_keys_not_both():
    words = _refused(**EYE, sun={"mode": "none"}, sun_lux=0)
    assert words == ("give the sun either as `sun` or as sun_lux/sun_azimuth_deg/"
                     "sun_elevation_deg, not both (got sun and sun_lux)")


def test_a_sun_that_gives_light_is_above_the_horizon():
    sun = dict(sun_lux=30000, sun_azimuth_deg=200)
    assert _refused(**EYE, **sun, sun_elevation_deg=0) == (
        "sun_elevation_deg = 0 is out of range: give more than 0, up to 90 deg")
    assert "give more than 0, up to 90 deg" in _refused(**EYE, **sun, sun_elevation_deg=91)
    assert _parse(**EYE, **sun, sun_elevation_deg=90).sun.elevation_deg == 90.0
    assert _parse(**EYE, **sun, sun_elevation_deg=0.5).sun.elevation_deg == 0.5
    assert "elevation_deg = 0 is out of range: give more than 0" in _refused(**EYE, sun={
        "mode": "direction", "lux": 30000, "azimuth_deg": 200, "elevation_deg": 0})


def test_a_site_sun_needs_its_time():
    words = _refused(**EYE, sun={"mode": "site", "lux": 40000})
    assert words.startswith("sun mode site needs `when`, the time at the site")
    assert '"when": "2026-11-27T15:00"' in words and "None" not in words


def test_a_sun_of_zero_lux_is_no_sun_even_at_night():
    night = _parse(**EYE, sun={"mode": "site", "lux": 0, "when": "2026-11-27T23:00"})
    assert night.sun.mode == "none"
    assert _parse(**EYE, sun={"mode": "direction", "lux": 0, "azimuth_deg": 0,
                              "elevation_deg": -30}).sun.mode == "none"
    day = _parse(**EYE, sun={"mode": "site", "lux": 40000, "when": "2026-11-27T23:00"})
    assert day.sun.mode == "site"  # lights.py says this sun is below the horizon


def test_huge_numbers_say_the_range_and_echoed_values_are_cut():
    huge = int("9" * 300)
    words = _refused(ambient_lux=huge, viewpoint=[170, 2, 0])
    assert words == "ambient_lux = 1e+300 is out of range: give 0.001 to 200000 lx"
    words = _refused(ambient_lux=huge * 10 ** 20, viewpoint=[170, 2, 0])  # not a float
    assert words.startswith("ambient_lux = 9999") and words.endswith(
        "is out of range: give 0.001 to 200000 lx") and len(words) < 110
    assert "out of range: give 0.02 to 2 dE00" in _refused(**EYE, target_stderr=float("inf"))
    assert "outside 0..20 mm" in _refused(**EYE, lengths_mm=[0, huge * 10 ** 20])
    assert "viewpoint d_m = " in _refused(ambient_lux=5, viewpoint=[170, huge * 10 ** 20, 0])
    long = "x" * 500
    for data in ({"ambient_lux": long, "viewpoint": [170, 2, 0]}, {**EYE, "light": long},
                 {**EYE, "tables": long}, {**EYE, "pixel": long}, {**EYE, "image": [long]},
                 {**EYE, "viewpoint": long}, {**EYE, "lengths_mm": [0, long]},
                 {**EYE, "sun": {"mode": long}}, {**EYE, long: 1},
                 {**EYE, "sun": {"mode": "site", "lux": 1, "when": long}}):
        words = _refused(**data)
        assert "x" * (MAX_SHOWN_CHARS + 1) not in words and "..." in words, words
