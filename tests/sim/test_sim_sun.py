"""grassd.sim.sun: solar position, finding the sun in a map, restoring a clipped sun."""

from __future__ import annotations

import datetime as dt

import numpy as np
import pytest

from grassd.sim import hdri, sun
from grassd.sim import lighting as L
from grassd.sim.errors import LightingError

LUMA = np.array([0.2126, 0.7152, 0.0722])
UTC = dt.UTC


# ---------------------------------------------------------------------------- sun position


@pytest.mark.parametrize(
    ("lat", "lon", "day", "declination"),
    [
        # solstices/equinox 2024; declination from the almanac (deg)
        (40.0, 0.0, dt.date(2024, 6, 20), 23.44),
        (52.0, 13.4, dt.date(2024, 6, 20), 23.44),
        (-33.9, 18.4, dt.date(2024, 12, 21), -23.44),
        (0.0, -60.0, dt.date(2024, 3, 20), 0.0),
    ],
)
def test_solar_noon_elevation(lat, lon, day, declination):
    """The day's highest apparent elevation is 90 - |lat - declination| (+ refraction)."""
    start = dt.datetime(day.year, day.month, day.day, tzinfo=UTC) - dt.timedelta(
        hours=lon / 15.0) + dt.timedelta(hours=11)
    best = max(
        (sun.sun_position(lat, lon, start + dt.timedelta(minutes=m)) for m in range(0, 120, 2)),
        key=lambda p: p[1],
    )
    assert best[1] == pytest.approx(90.0 - abs(lat - declination), abs=0.5)
    if abs(lat - declination) > 5:  # azimuth at noon: due south (north hemisphere) or north
        assert min(abs(best[0] - (180.0 if lat > declination else 0.0)),
                   abs(best[0] - 360.0)) < 3.0


def test_sun_position_known_value_and_timezones():
    # Greenwich, 2024-06-20 12:00 UTC: declination 23.43 deg -> noon elevation 90 - 51.48 +
    # 23.43 = 61.95 (+0.01 refraction); equation of time -1.6 min puts noon at 12:01.6 UTC, so
    # the sun is 0.4 deg of hour angle short of due south: azimuth about 179.2
    az, el = sun.sun_position(51.4769, 0.0, dt.datetime(2024, 6, 20, 12, 0, tzinfo=UTC))
    assert el == pytest.approx(61.96, abs=0.1) and az == pytest.approx(179.2, abs=0.5)
    # the same instant in another zone gives the same answer
    cest = dt.timezone(dt.timedelta(hours=2))
    az2, el2 = sun.sun_position(51.4769, 0.0, dt.datetime(2024, 6, 20, 14, 0, tzinfo=cest))
    assert (az2, el2) == pytest.approx((az, el), abs=1e-9)
    with pytest.raises(LightingError, match="no timezone"):
        sun.sun_position(51.0, 0.0, dt.datetime(2024, 6, 20, 12, 0))
    with pytest.raises(LightingError, match="latitude"):
        sun.sun_position(91.0, 0.0, dt.datetime(2024, 6, 20, 12, 0, tzinfo=UTC))
    with pytest.raises(LightingError, match="longitude"):
        sun.sun_position(10.0, 200.0, dt.datetime(2024, 6, 20, 12, 0, tzinfo=UTC))


# ---------------------------------------------------------------------------- find the sun


def _sky_with_sun(az, el, h=256, radius_deg=0.6, sun_radiance=5e4, sky=1.0):
    """Uniform sky/ground plus a disc of given radius around (az, el), in the convention."""
    w = 2 * h
    v, u = np.meshgrid((np.arange(h) + 0.5) / h, (np.arange(w) + 0.5) / w, indexing="ij")
    d = L.uv_to_direction(u, v)
    s = L.direction_from_azimuth_elevation(az, el)
    env = np.full((h, w, 3), sky, np.float32)
    env[v > 0.5] = 0.3 * sky
    env[d @ s > np.cos(np.radians(radius_deg))] = sun_radiance
    return env


@pytest.mark.parametrize(("az", "el"), [(135.0, 40.0), (90.0, 25.0), (88.0, 60.0),
                                        (300.0, 10.0)])
def test_find_sun_synthetic(az, el):
    """Including suns on the u = 0 seam (azimuth 90 = east = left/right edge)."""
    env = _sky_with_sun(az, el)
    found = sun.find_sun(env)
    assert found is not None
    az2, el2 = L.azimuth_elevation_from_direction(found.direction)
    assert el2 == pytest.approx(el, abs=0.5)
    assert min(abs(az2 - az), 360 - abs(az2 - az)) * np.cos(np.radians(el)) < 0.5
    disc = 2 * np.pi * (1 - np.cos(np.radians(0.6)))
    assert found.solid_angle_sr == pytest.approx(disc, rel=0.5)
    np.testing.assert_allclose(found.mean_radiance_rgb, 5e4, rtol=1e-6)


def test_find_sun_rejects_broad_dim_or_low_regions():
    assert sun.find_sun(np.ones((64, 128, 3), np.float32)) is None  # no contrast
    assert sun.find_sun(_sky_with_sun(100.0, 40.0, radius_deg=5.0)) is None  # a softbox
    assert sun.find_sun(_sky_with_sun(100.0, 40.0, sun_radiance=50.0)) is None  # dim lamp
    below = _sky_with_sun(100.0, 40.0, sun_radiance=1.0)
    below[200, 30] = 1e6  # brightest texel of the map is below the horizon
    assert sun.find_sun(below) is None


def test_find_sun_on_city_is_the_maps_maximum(shared_hdri):
    env = hdri.load_hdri(shared_hdri("city"))
    found = sun.find_sun(env)
    assert found is not None
    az, el = L.azimuth_elevation_from_direction(found.direction)
    assert 40.0 < el < 55.0  # a late-morning sun; 47.8 deg measured
    lum = env.astype(np.float64) @ LUMA
    r, c = np.unravel_index(lum.argmax(), lum.shape)
    peak_dir = L.uv_to_direction((c + 0.5) / env.shape[1], (r + 0.5) / env.shape[0])
    assert np.degrees(np.arccos(np.clip(peak_dir @ found.direction, -1, 1))) < 0.5
    mask = sun.sun_mask(env)
    assert mask[r, c] and mask.sum() <= 20
    assert found.solid_angle_sr < sun.MAX_SUN_SOLID_ANGLE_SR
    assert found.mean_radiance_rgb.min() > 1e4  # the clamp level of the file was 32000


@pytest.mark.parametrize(("name", "has_sun"), [("courtyard", False), ("studio", False),
                                               ("forest", True), ("interior", True)])
def test_find_sun_on_the_other_shared_maps(shared_hdri, name, has_sun):
    found = sun.find_sun(hdri.load_hdri(shared_hdri(name)))
    assert (found is not None) == has_sun


# ---------------------------------------------------------------------- clipped-sun restore


def test_city_clipped_sun_restored_from_total_lux(shared_hdri):
    env = hdri.load_hdri(shared_hdri("city"))
    total = 80000.0
    lit = L.build_lighting(env, total, sun_from_hdri=True, day_of_year=239)
    found = sun.find_sun(env)
    mask = sun.sun_mask(env)
    lum = env.astype(np.float64) @ LUMA
    cw = L.horizontal_cosine_weights(*env.shape[:2])
    e_map = float((lum * cw[:, None]).sum())
    e_sun = float((lum * cw[:, None] * mask).sum())
    f_map = e_sun / e_map
    assert 0.2 < f_map < 0.35  # the clipped sun gives only ~27 % of the map's light
    # Erbs decomposition at the found elevation, recomputed with pvlib directly
    from pvlib import irradiance

    _, el = L.azimuth_elevation_from_direction(found.direction)
    out = irradiance.erbs(total / sun.GLOBAL_EFFICACY_LM_W, 90.0 - el, 239)
    f_model = 1.0 - float(out["dhi"]) / (total / sun.GLOBAL_EFFICACY_LM_W)
    assert 0.6 < f_model < 0.9  # a clear sky at ~48 deg: most light is direct
    # the rule: the sky gets (1 - f) of the total, the sun region is kept, the deficit is added
    k = (1.0 - f_model) * total / (e_map - e_sun)
    assert lit.env_scale == pytest.approx(k, rel=1e-9)
    assert lit.sun_lux == pytest.approx(f_model * total - k * e_sun, rel=1e-6)
    assert lit.total_lux == pytest.approx(total, rel=1e-6)
    assert LUMA @ lit.horizontal_irradiance_rgb == pytest.approx(total, rel=1e-6)
    np.testing.assert_allclose(lit.sun_direction, found.direction, atol=1e-12)
    assert LUMA @ lit.sun_irradiance_rgb == pytest.approx(
        lit.sun_lux / np.sin(np.radians(el)), rel=1e-9)
    assert lit.sun_lux > 0.6 * total  # the restored sun dominates, as on a real sunny day


def test_two_readings_sky_gets_the_shaded_reading(shared_hdri):
    env = hdri.load_hdri(shared_hdri("city"))
    lit = L.build_lighting(env, 15000.0, sun_lux=65000.0, sun_from_hdri=True)
    mask = sun.sun_mask(env)
    sky = lit.env * ~mask[..., None]
    assert L.horizontal_illuminance(sky) == pytest.approx(15000.0, rel=1e-5)
    assert lit.total_lux == pytest.approx(80000.0, rel=1e-6)
    # the map's clipped sun (scaled) plus the directional deficit make the measured sun lux
    assert L.horizontal_illuminance(lit.env * mask[..., None]) + lit.sun_lux == pytest.approx(
        65000.0, rel=1e-5)


def test_unclipped_sun_is_trusted_as_it_is():
    env = _sky_with_sun(200.0, 50.0, h=128, radius_deg=1.0, sun_radiance=3e4)
    e_map = L.horizontal_illuminance(env)
    mask = sun.sun_mask(env)
    f_map = L.horizontal_illuminance(env * mask[..., None]) / e_map
    assert f_map > 0.85  # a strong sun, more than the clear-sky model asks for
    lit = L.build_lighting(env, 90000.0, sun_from_hdri=True)
    assert lit.sun_direction is None and lit.sun_lux == 0.0
    assert lit.env_scale == pytest.approx(90000.0 / e_map, rel=1e-9)
    assert lit.total_lux == pytest.approx(90000.0, rel=1e-6)


def test_no_sun_in_map_scales_everything(shared_hdri):
    env = hdri.load_hdri(shared_hdri("courtyard"))
    lit = L.build_lighting(env, 9000.0, sun_from_hdri=True)
    assert lit.sun_direction is None and lit.sun_lux == 0.0
    assert lit.total_lux == pytest.approx(9000.0, rel=1e-6)
    assert any("no compact sun" in n for n in lit.notes)
    with pytest.raises(LightingError, match="no compact sun is visible"):
        L.build_lighting(env, 9000.0, sun_lux=20000.0, sun_from_hdri=True)


def test_clear_sky_direct_fraction_behaviour():
    # overcast (low reading) -> mostly diffuse; clear (high reading) -> mostly direct
    assert sun.clear_sky_direct_fraction(10000.0, 45.0) < 0.2
    assert sun.clear_sky_direct_fraction(85000.0, 50.0) > 0.7
    assert sun.clear_sky_direct_fraction(50000.0, 2.0) == 0.0


def test_reading_brighter_than_sunlight_above_the_atmosphere_is_flagged():
    env = _sky_with_sun(200.0, 10.0, h=128, radius_deg=1.0, sun_radiance=300.0)
    split = sun.split_sun(env, 60000.0)  # > 133 klux x sin(10 deg) = 23 klux
    assert any("exceeds the" in n and "above the atmosphere" in n for n in split.notes)
    assert not any("above the atmosphere" in n
                   for n in sun.split_sun(env, 15000.0).notes)
