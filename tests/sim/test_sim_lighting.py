"""grassd.sim.lighting: conventions, lux scaling, rotation, Lighting and the env sampler."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from grassd.sim import hdri
from grassd.sim import lighting as L
from grassd.sim.errors import LightingError

LUMA = np.array([0.2126, 0.7152, 0.0722])


def _lookup(env, d):
    """Independent nearest-texel lookup written from the convention's text."""
    h, w = env.shape[:2]
    u = np.mod(np.arctan2(d[:, 1], d[:, 0]) / (2 * np.pi), 1.0)
    v = np.arccos(np.clip(d[:, 2], -1, 1)) / np.pi
    return env[np.minimum((v * h).astype(int), h - 1), (u * w).astype(int) % w]


def _midpoint_illuminance(env):
    """The brief's formula: sum Y cos(theta) (2 pi / W)(pi / H) sin(theta), texel centres."""
    h, w = env.shape[:2]
    theta = (np.arange(h) + 0.5) * np.pi / h
    wgt = np.where(theta < np.pi / 2, np.cos(theta), 0.0) * np.sin(theta) * (2 * np.pi / w) * (
        np.pi / h)
    return float(((env.astype(np.float64) @ LUMA) * wgt[:, None]).sum())


# ------------------------------------------------------------------------------ convention


def test_compass_and_map_convention():
    np.testing.assert_allclose(L.direction_from_azimuth_elevation(0, 0), [0, 1, 0], atol=1e-15)
    np.testing.assert_allclose(L.direction_from_azimuth_elevation(90, 0), [1, 0, 0], atol=1e-15)
    np.testing.assert_allclose(L.direction_from_azimuth_elevation(123, 90), [0, 0, 1],
                               atol=1e-15)
    u, v = L.direction_to_uv(np.array([[1, 0, 0], [0, 1, 0], [-1, 0, 0], [0, -1, 0],
                                       [0, 0, 1], [0, 0, -1]], float))
    np.testing.assert_allclose(u[:4], [0.0, 0.25, 0.5, 0.75])  # east, north, west, south
    np.testing.assert_allclose(v, [0.5, 0.5, 0.5, 0.5, 0.0, 1.0])
    rng = np.random.default_rng(0)
    az, el = rng.uniform(0, 360, 1000), rng.uniform(-89, 89, 1000)
    d = L.direction_from_azimuth_elevation(az, el)
    az2, el2 = L.azimuth_elevation_from_direction(d)
    np.testing.assert_allclose(az2, az, atol=1e-9)
    np.testing.assert_allclose(el2, el, atol=1e-9)
    # compass azimuth A sits at u = (90 - A) / 360
    np.testing.assert_allclose(L.direction_to_uv(d)[0], np.mod((90 - az) / 360, 1), atol=1e-12)
    np.testing.assert_allclose(L.uv_to_direction(*L.direction_to_uv(d)), d, atol=1e-12)


def test_env_radiance_nearest_texel():
    env = np.arange(8 * 16 * 3, dtype=np.float32).reshape(8, 16, 3)
    rng = np.random.default_rng(1)
    d = rng.normal(size=(500, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    np.testing.assert_array_equal(L.env_radiance(env, d), _lookup(env, d))


# ------------------------------------------------------------------------------ illuminance


@pytest.mark.parametrize("h", [4, 5, 64, 512])
def test_uniform_map_gives_pi_l_exactly(h):
    env = np.full((h, 2 * h, 3), 2.5, np.float32)
    assert L.horizontal_illuminance(env) == pytest.approx(np.pi * 2.5, rel=1e-12)
    np.testing.assert_allclose(L.horizontal_irradiance_rgb(env), np.pi * 2.5, rtol=1e-12)
    np.testing.assert_allclose(L.texel_solid_angles(h, 2 * h).sum() * 2 * h, 4 * np.pi,
                               rtol=1e-12)
    # the lower hemisphere does not light an upward plane
    env[(h + 1) // 2:] = 1000.0
    if h % 2 == 0:
        assert L.horizontal_illuminance(env) == pytest.approx(np.pi * 2.5, rel=1e-12)


@pytest.mark.parametrize("name", ["city", "courtyard", "forest", "interior", "studio"])
def test_real_map_illuminance_matches_midpoint_quadrature(shared_hdri, name):
    env = hdri.load_hdri(shared_hdri(name))
    e_exact = L.horizontal_illuminance(env)
    e_mid = _midpoint_illuminance(env)
    assert abs(e_exact - e_mid) / e_mid < 1e-5


def test_real_map_illuminance_by_cosine_weighted_monte_carlo(shared_hdri):
    env = hdri.load_hdri(shared_hdri("courtyard"))
    rng = np.random.default_rng(7)
    n = 2_000_000
    # cosine-weighted hemisphere: E = pi * mean(Y)
    r, phi = np.sqrt(rng.random(n)), 2 * np.pi * rng.random(n)
    d = np.stack([r * np.cos(phi), r * np.sin(phi), np.sqrt(1 - r * r)], axis=1)
    y = _lookup(env, d).astype(np.float64) @ LUMA
    est, err = np.pi * y.mean(), np.pi * y.std() / np.sqrt(n)
    e = L.horizontal_illuminance(env)
    assert abs(est - e) < 4 * err, (est, e, err)
    assert err / e < 0.01  # the check is sharp


def test_build_lighting_scales_real_map_to_lux(shared_hdri):
    env = hdri.load_hdri(shared_hdri("courtyard"))
    lit = L.build_lighting(env, 12345.0)
    assert L.horizontal_illuminance(lit.env) == pytest.approx(12345.0, rel=1e-6)
    assert _midpoint_illuminance(lit.env) == pytest.approx(12345.0, rel=2e-5)
    assert lit.env_scale == pytest.approx(12345.0 / L.horizontal_illuminance(env), rel=1e-12)
    assert lit.ambient_lux == pytest.approx(12345.0, rel=1e-6) and lit.sun_lux == 0.0
    assert lit.sun_direction is None and (lit.sun_irradiance_rgb == 0).all()
    assert LUMA @ lit.horizontal_irradiance_rgb == pytest.approx(12345.0, rel=1e-6)
    np.testing.assert_allclose(lit.env_unscaled, env, rtol=1e-6)
    assert lit.env.dtype == np.float32 and not lit.env.flags.writeable
    with pytest.raises(dataclasses.FrozenInstanceError):
        lit.env_scale = 1.0


def test_build_lighting_from_bundled_default_site():
    lit = L.build_lighting(hdri.default_site_hdri(), 30000.0)
    assert lit.env.shape == (128, 256, 3)
    assert lit.total_lux == pytest.approx(30000.0, rel=1e-6)


def test_directional_sun_from_horizontal_lux():
    env = np.full((32, 64, 3), 1.0, np.float32)
    lit = L.build_lighting(env, 20000.0, sun_lux=50000.0, sun_azimuth_deg=135.0,
                           sun_elevation_deg=30.0)
    a, e = np.radians(135.0), np.radians(30.0)
    np.testing.assert_allclose(lit.sun_direction,
                               [np.sin(a) * np.cos(e), np.cos(a) * np.cos(e), np.sin(e)],
                               atol=1e-12)
    # perpendicular = 50000 / sin 30 = 100000 lux, default colour has Y = 1
    assert LUMA @ lit.sun_irradiance_rgb == pytest.approx(100000.0, rel=1e-9)
    np.testing.assert_allclose(lit.sun_irradiance_rgb / 100000.0, L.DEFAULT_SUN_COLOUR)
    assert LUMA @ lit.horizontal_irradiance_rgb == pytest.approx(70000.0, rel=1e-6)
    assert lit.total_lux == pytest.approx(70000.0, rel=1e-6)
    # D55 is warmer than the D65 white: R > G > B
    assert L.DEFAULT_SUN_COLOUR[0] > L.DEFAULT_SUN_COLOUR[1] > L.DEFAULT_SUN_COLOUR[2]
    warm = L.build_lighting(env, 20000.0, sun_lux=50000.0, sun_azimuth_deg=135.0,
                            sun_elevation_deg=30.0, sun_colour=(2.0, 1.0, 0.5))
    assert LUMA @ warm.sun_irradiance_rgb == pytest.approx(100000.0, rel=1e-9)
    assert warm.sun_irradiance_rgb[0] / warm.sun_irradiance_rgb[2] == pytest.approx(4.0)


def test_a_sun_added_to_a_built_light_is_the_light_built_with_that_sun(shared_hdri):
    """``add_sun`` keeps the scaled map and its sums (the studio's time of day changes only the
    sun) and gives every field ``build_lighting`` gives for the same readings, bit for bit."""
    raw = hdri.load_hdri(shared_hdri("forest"))
    base = L.build_lighting(raw, 5000.0, rotation_deg=30.0)
    for lux, az, el in ((40000.0, 200.0, 20.0), (8000.0, -30.0, 60.0), (0.0, 10.0, 5.0)):
        sunlit = L.add_sun(base, lux, az, el)
        built = L.build_lighting(raw, 5000.0, sun_lux=lux, sun_azimuth_deg=az,
                                 sun_elevation_deg=el, rotation_deg=30.0)
        assert sunlit.env is base.env and sunlit.env_map is base.env_map
        for f in dataclasses.fields(L.Lighting):
            a, b = getattr(sunlit, f.name), getattr(built, f.name)
            assert np.array_equal(a, b) if isinstance(a, np.ndarray) else a == b, f.name
        assert np.array_equal(sunlit.horizontal_irradiance_rgb, built.horizontal_irradiance_rgb)
    with pytest.raises(LightingError, match="below the horizon"):
        L.add_sun(base, 5000.0, 10.0, -2.0)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        (dict(ambient_lux=0.0), r"ambient lux 0 lx must be > 0"),
        (dict(ambient_lux=-5.0), r"must be > 0"),
        (dict(ambient_lux=250000.0), r"exceeds 200000 lx"),
        (dict(ambient_lux=float("nan")), r"not finite"),
        (dict(ambient_lux="bright"), r"not a number"),
        (dict(ambient_lux=1000.0, sun_lux=-1.0), r"sun lux -1 lx must be >= 0"),
        (dict(ambient_lux=1000.0, sun_lux=5000.0), r"without a sun direction"),
        (dict(ambient_lux=1000.0, sun_azimuth_deg=10.0, sun_elevation_deg=20.0),
         r"without the sun lux"),
        (dict(ambient_lux=1000.0, sun_lux=5000.0, sun_azimuth_deg=10.0),
         r"both the sun azimuth and the sun elevation"),
        (dict(ambient_lux=1000.0, sun_lux=5000.0, sun_azimuth_deg=10.0,
              sun_elevation_deg=-3.0), r"below the horizon"),
        (dict(ambient_lux=1000.0, sun_lux=5000.0, sun_azimuth_deg=10.0,
              sun_elevation_deg=0.0), r"below the horizon"),
        (dict(ambient_lux=1000.0, sun_lux=5000.0, sun_azimuth_deg=10.0,
              sun_elevation_deg=95.0), r"exceeds 90"),
        (dict(ambient_lux=1000.0, sun_lux=60000.0, sun_azimuth_deg=10.0,
              sun_elevation_deg=10.0), r"more than sunlight can give"),
        (dict(ambient_lux=150000.0, sun_lux=60000.0, sun_azimuth_deg=10.0,
              sun_elevation_deg=60.0), r"ambient \+ sun lux"),
        (dict(ambient_lux=1000.0, sun_from_hdri=True, sun_azimuth_deg=10.0,
              sun_elevation_deg=20.0), r"do not also give a sun azimuth"),
        (dict(ambient_lux=1000.0, rotation_deg=float("inf")), r"rotation"),
        (dict(ambient_lux=1000.0, sun_lux=5000.0, sun_azimuth_deg=10.0,
              sun_elevation_deg=40.0, sun_colour=(1.0, -1.0, 0.0)), r"sun colour"),
    ],
)
def test_build_lighting_rejects_bad_values(kwargs, message):
    env = np.ones((16, 32, 3), np.float32)
    with pytest.raises(LightingError, match=message) as info:
        L.build_lighting(env, **kwargs)
    assert "\n" not in str(info.value)


# ------------------------------------------------------------------------------- rotation


def test_rotation_moves_a_bright_spot_to_the_predicted_column():
    h, w = 64, 128
    env = np.full((h, w, 3), 0.1, np.float32)
    env[20, 10] = 100.0
    for rot, col in [(90.0, 10 + 32), (-45.0, 10 - 16), (360.0 + 180.0, 10 + 64)]:
        out = L.rotate_env(env, rot)
        assert np.unravel_index(out[..., 0].argmax(), (h, w)) == (20, col % w)
    # direction view: the spot at phi moves to phi + rotation (counter-clockwise, towards +y)
    d0 = L.uv_to_direction((10 + 0.5) / w, (20 + 0.5) / h)
    rot = np.radians(90.0)
    rz = np.array([[np.cos(rot), -np.sin(rot), 0], [np.sin(rot), np.cos(rot), 0], [0, 0, 1]])
    assert L.env_radiance(L.rotate_env(env, 90.0), rz @ d0)[0] == 100.0
    # fractional: a quarter column splits the spot 3:1 and keeps the illuminance exactly
    out = L.rotate_env(env, 0.25 * 360.0 / w)
    np.testing.assert_allclose(out[20, 10:12, 0], [0.75 * 99.9 + 0.1, 0.25 * 99.9 + 0.1],
                               rtol=1e-6)
    assert L.horizontal_illuminance(out) == pytest.approx(L.horizontal_illuminance(env),
                                                          rel=1e-7)


def test_flip_mirrors_east_west():
    h, w = 32, 64
    env = np.full((h, w, 3), 0.1, np.float32)
    d = L.direction_from_azimuth_elevation(60.0, 20.0)  # north-east
    row, col = (int(x) for x in (L.direction_to_uv(d)[1] * h, L.direction_to_uv(d)[0] * w))
    env[row, col] = 50.0
    flipped = L.orient_env(env, flip=True)
    mirrored = L.direction_from_azimuth_elevation(120.0, 20.0)  # phi -> -phi: ENE -> ESE
    assert L.env_radiance(flipped, mirrored)[0] == 50.0
    assert L.env_radiance(flipped, d)[0] == pytest.approx(0.1)
    lit = L.build_lighting(env, 1000.0, flip=True, rotation_deg=30.0)
    assert lit.flipped and lit.rotation_deg == 30.0
