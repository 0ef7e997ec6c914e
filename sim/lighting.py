"""Light for the renderer: environment-map geometry, lux scaling, the sun, importance sampling.

Pure numpy (no Taichi): the kernels in :mod:`grassd.sim.kernels` are ports of the reference
functions here (:func:`sample_env`, :func:`env_pdf`, :func:`env_radiance`).

Conventions (fixed for all of ``grassd.sim`` and for exported scenes)
-------------------------------------------------------------------
World frame
    Metres, right-handed, z up, +x east, +y north (ENU). A compass azimuth A (degrees from
    north, clockwise seen from above) and elevation e (degrees above the horizon) give the unit
    direction ``(sin A cos e, cos A cos e, sin e)``.
Environment map
    An ``(H, W, 3)`` array with ``W = 2 H``. Direction ``(x, y, z)`` maps to
    ``u = atan2(y, x) / 2 pi (mod 1)`` and ``v = acos(z) / pi``; ``u = 0`` is the image's left
    edge, ``v = 0`` its top row; texel (row i, column j) = ``(floor(v H), floor(u W))`` and covers
    polar angles ``theta in [pi i / H, pi (i + 1) / H]`` and ``phi = atan2(y, x) in
    [2 pi j / W, 2 pi (j + 1) / W]``. So the top row is the zenith, the left edge looks east
    (compass 90 deg), column W/4 north, W/2 west, 3W/4 south; compass azimuth A sits at
    ``u = (90 - A) / 360 (mod 1)``.
    Lookups are piecewise constant: a direction sees the radiance of the texel it falls in
    (nearest texel, no filtering); every integral below is the exact integral of that function.
    Note: u grows counter-clockwise seen from above, whereas ordinary panoramas (cameras, Poly
    Haven, Blender, Mitsuba) grow clockwise (turning right moves right in the image). Read in
    this convention such a file is mirrored east-west; pass ``flip=True`` to
    :func:`orient_env` / :func:`build_lighting` to read it unmirrored (a file in Blender's
    world convention, ``u = 0.5 - atan2(y, x) / 2 pi``, is then reproduced exactly with
    ``flip=True, rotation_deg=180``). Mitsuba 3's ``envmap`` looks up
    ``u = atan2(x_l, -z_l) / 2 pi, v = acos(y_l) / pi`` in its local frame; its
    ``to_world = [[0, 0, -1], [1, 0, 0], [0, 1, 0]]`` (a reflection, det -1; checked with
    mitsuba 3 scalar_rgb) reproduces this convention with the file as it is. Mitsuba filters
    the map bilinearly; upsampling it k-fold with ``np.repeat`` makes its lookups equal ours
    except within half a fine texel of the coarse texel borders.
Rotation
    ``rotation_deg`` turns the map content about +z, positive counter-clockwise seen from above
    (content moves towards +y): a feature at azimuth angle phi goes to ``phi + rotation``, i.e.
    ``u + rotation / 360``. Applied by rolling columns; a shift that is not a whole number of
    columns is linearly interpolated between the two neighbouring whole-column rolls (which keeps
    every row's sum, hence the illuminance and the sampling marginals, exactly).
Radiance and illuminance
    Linear Rec.709 RGB; luminance ``Y = 0.2126 R + 0.7152 G + 0.0722 B``. The illuminance on an
    upward-facing horizontal plane is ``E = sum_texels Y * w_i`` with
    ``w_i = integral over the texel of max(0, cos theta) d omega
    = (2 pi / W) (sin^2 min(theta_i+1, pi/2) - sin^2 theta_i) / 2`` (upper hemisphere only).
    This is the exact integral of the piecewise-constant map, so a uniform map of radiance L
    gives E = pi L exactly at any resolution; it differs from the midpoint formula
    ``Y cos(theta_c) (2 pi / W)(pi / H) sin(theta_c)`` by ``O(1/H^2)``
    (for a uniform map the midpoint sum is high by 6.3e-6 at H = 512, 1.0e-4 at H = 128).
    The scale k makes E of ``k * map`` equal the measured lux, so scaled radiance is in
    cd/m^2 (nits) and irradiance per channel "lux-like" (the luminance-weighted sum of the
    three channels is lux).
Sun
    A directional light: unit ``sun_direction`` towards the sun and ``sun_irradiance_rgb`` on a
    plane perpendicular to it (same units). A sun lux reading is taken on the same horizontal
    meter, so the perpendicular irradiance is ``sun_lux / sin(elevation)``.
Importance sampling
    :mod:`grassd.sim.env_sampler` (per normal bin, two levels). Texel weight
    ``(Y + floor * Y_mean) * Omega_i`` (``Omega_i`` the texel solid angle, ``Y_mean`` the
    solid-angle mean luminance, ``floor`` = :data:`ENV_SAMPLING_FLOOR`), so black texels keep
    a small probability.
"""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass, field, replace
from functools import cached_property

import numpy as np

from grassd.sim.errors import LightingError
from grassd.sim.hdri import MAX_TEXELS, REC709_LUMINANCE, check_env, load_hdri

__all__ = [
    "DEFAULT_SUN_COLOUR",
    "ENV_SAMPLING_FLOOR",
    "MAX_LUX",
    "MAX_SUN_PERPENDICULAR_LUX",
    "Lighting",
    "add_sun",
    "azimuth_elevation_from_direction",
    "build_lighting",
    "direction_from_azimuth_elevation",
    "direction_to_uv",
    "env_radiance",
    "horizontal_cosine_weights",
    "horizontal_illuminance",
    "horizontal_irradiance_rgb",
    "normalised_colour",
    "orient_env",
    "rotate_env",
    "sun_irradiance_from_lux",
    "texel_solid_angles",
    "uv_to_direction",
]

log = logging.getLogger(__name__)

#: Largest accepted lux reading (the brightest natural daylight is about 130 klux).
MAX_LUX: float = 200_000.0
#: Largest accepted sun illuminance perpendicular to the sun: 1.2 x the extraterrestrial solar
#: illuminance (about 128-133 klux). ``sun_lux / sin(elevation)`` above it means the reading or
#: the elevation is wrong.
MAX_SUN_PERPENDICULAR_LUX: float = 160_000.0
#: Default sun colour: CIE D55 (x, y) = (0.33242, 0.34743), the usual stand-in for direct
#: sunlight at mid elevations (about 5500 K), as linear Rec.709 RGB (D65 white, no adaptation)
#: normalised to luminance Y = 1.
DEFAULT_SUN_COLOUR = np.array([1.10410717, 0.98689023, 0.82322847])
DEFAULT_SUN_COLOUR /= REC709_LUMINANCE @ DEFAULT_SUN_COLOUR  # Y = 1 with the 4-digit weights
DEFAULT_SUN_COLOUR.flags.writeable = False
#: Probability floor of the environment sampler, as a fraction of the mean luminance.
ENV_SAMPLING_FLOOR: float = 1e-3


# ------------------------------------------------------------------------------ directions


def direction_from_azimuth_elevation(azimuth_deg, elevation_deg) -> np.ndarray:
    """Unit vector(s) (..., 3) for compass azimuth (deg from north, clockwise) and elevation (deg).

    >>> direction_from_azimuth_elevation(90.0, 0.0).round(12) + 0.0  # east
    array([1., 0., 0.])
    """
    a = np.radians(np.asarray(azimuth_deg, dtype=np.float64))
    e = np.radians(np.asarray(elevation_deg, dtype=np.float64))
    return np.stack([np.sin(a) * np.cos(e), np.cos(a) * np.cos(e), np.sin(e)], axis=-1)


def azimuth_elevation_from_direction(directions) -> tuple[np.ndarray, np.ndarray]:
    """Compass azimuth in [0, 360) and elevation in [-90, 90], degrees, of direction(s) (..., 3)."""
    d = np.asarray(directions, dtype=np.float64)
    d = d / np.linalg.norm(d, axis=-1, keepdims=True)
    az = np.degrees(np.arctan2(d[..., 0], d[..., 1])) % 360.0
    el = np.degrees(np.arcsin(np.clip(d[..., 2], -1.0, 1.0)))
    return az, el


def direction_to_uv(directions) -> tuple[np.ndarray, np.ndarray]:
    """Map coordinates (u, v) in [0, 1) x [0, 1] of direction(s) (..., 3) (need not be unit)."""
    d = np.asarray(directions, dtype=np.float64)
    norm = np.linalg.norm(d, axis=-1)
    u = (np.arctan2(d[..., 1], d[..., 0]) / (2.0 * np.pi)) % 1.0
    v = np.arccos(np.clip(d[..., 2] / norm, -1.0, 1.0)) / np.pi
    return u, v


def uv_to_direction(u, v) -> np.ndarray:
    """Unit direction(s) (..., 3) of map coordinates u, v (inverse of :func:`direction_to_uv`)."""
    phi = 2.0 * np.pi * np.asarray(u, dtype=np.float64)
    theta = np.pi * np.asarray(v, dtype=np.float64)
    s = np.sin(theta)
    return np.stack([s * np.cos(phi), s * np.sin(phi), np.cos(theta)], axis=-1)


def _texel_index(directions, height: int, width: int) -> tuple[np.ndarray, np.ndarray]:
    u, v = direction_to_uv(directions)
    col = np.floor(u * width).astype(np.int64) % width
    row = np.minimum(np.floor(v * height).astype(np.int64), height - 1)
    return row, col


def env_radiance(env: np.ndarray, directions) -> np.ndarray:
    """Radiance (..., 3) seen in direction(s) (..., 3): nearest texel (piecewise constant)."""
    row, col = _texel_index(directions, env.shape[0], env.shape[1])
    return np.asarray(env)[row, col]


# ------------------------------------------------------------------------------- integrals


def texel_solid_angles(height: int, width: int) -> np.ndarray:
    """Exact solid angle (sr) of one texel in each row, shape (H,):
    ``(2 pi / W) (cos theta_i - cos theta_i+1)``. Sums to 4 pi over the map."""
    edges = np.cos(np.pi * np.arange(height + 1) / height)
    return (2.0 * np.pi / width) * (edges[:-1] - edges[1:])


def horizontal_cosine_weights(height: int, width: int) -> np.ndarray:
    """Per-row weight (H,) of one texel for horizontal illuminance, in sr:
    ``integral over the texel of max(0, cos theta) d omega``. Sums to pi over the map."""
    theta = np.minimum(np.pi * np.arange(height + 1) / height, np.pi / 2.0)
    s2 = np.sin(theta) ** 2
    return (np.pi / width) * (s2[1:] - s2[:-1])


def horizontal_irradiance_rgb(radiance: np.ndarray) -> np.ndarray:
    """Per-channel irradiance (3,) on an upward-facing horizontal plane from an equirectangular
    radiance map (H, W, 3): ``sum L * integral max(0, cos theta) d omega`` (exact for the
    piecewise-constant map). Units: radiance units x sr (nits -> lux-like per channel)."""
    env = np.asarray(radiance)
    w = horizontal_cosine_weights(env.shape[0], env.shape[1])
    upper = int(np.count_nonzero(w))
    return np.einsum("hwc,h->c", env[:upper].astype(np.float64), w[:upper])


def horizontal_illuminance(radiance: np.ndarray) -> float:
    """Illuminance on an upward-facing horizontal plane, E = sum Y w (lux if radiance is nits).

    >>> float(round(horizontal_illuminance(np.ones((8, 16, 3))) / np.pi, 12))
    1.0
    """
    return float(REC709_LUMINANCE @ horizontal_irradiance_rgb(radiance))


# ----------------------------------------------------------------------------- orientation


def rotate_env(img: np.ndarray, rotation_deg: float) -> np.ndarray:
    """Turn a map's content about +z by ``rotation_deg`` (counter-clockwise seen from above).

    Content at column u moves to ``u + rotation_deg / 360``. Whole-column shifts are exact
    rolls; fractional shifts interpolate linearly between the two neighbouring rolls (row sums
    and hence the horizontal illuminance are kept exactly). Returns float32 (H, W, 3): no
    turn (a shift under a millionth of a texel) gives a view of ``img`` itself when it is
    float32 and contiguous (a kept map and its light then share one copy).
    """
    if not np.isfinite(rotation_deg):
        raise LightingError(f"HDRI rotation {rotation_deg} deg is not a finite number")
    arr = np.asarray(img, dtype=np.float32)
    width = arr.shape[1]
    shift = (float(rotation_deg) / 360.0 * width) % width
    whole = int(np.floor(shift))
    frac = shift - whole
    if frac < 1e-6 or frac > 1.0 - 1e-6:
        whole = int(round(shift)) % width
        if whole == 0:
            return np.ascontiguousarray(arr).view()
        return np.ascontiguousarray(np.roll(arr, whole, axis=1))
    a = np.roll(arr, whole, axis=1)
    b = np.roll(arr, whole + 1, axis=1)
    return np.ascontiguousarray((1.0 - frac) * a + frac * b, dtype=np.float32)


def orient_env(img: np.ndarray, rotation_deg: float = 0.0, flip: bool = False) -> np.ndarray:
    """Bring a stored panorama into the convention: optional east-west mirror (``flip``, for
    ordinary clockwise panoramas: reverses the column order, phi -> -phi), then
    :func:`rotate_env`. Returns float32 (H, W, 3)."""
    arr = np.asarray(img, dtype=np.float32)
    if flip:
        arr = arr[:, ::-1]  # texel j <-> W - 1 - j: phi -> -phi exactly
    return rotate_env(arr, rotation_deg)


# -------------------------------------------------------------------------------- lighting


def _readonly(a: np.ndarray) -> np.ndarray:
    a = np.ascontiguousarray(a)
    a.flags.writeable = False
    return a


@dataclass(frozen=True, eq=False)
class Lighting:
    """The light at the display, in the conventions of this module.

    ``env``: (H, W, 3) float32 scaled radiance (nits), read-only. ``env_scale``: k such that
    ``env = k * map`` (map = the file after :func:`orient_env`). ``sun_direction``: (3,) unit
    vector towards the sun, or None. ``sun_irradiance_rgb``: (3,) sun irradiance on a plane
    perpendicular to it (lux-like linear Rec.709; zeros without a sun). ``ambient_lux``: what
    ``env`` gives on the upward horizontal plane; ``sun_lux``: what the sun gives there (0
    without a sun). ``rotation_deg`` / ``flipped``: how the file was oriented. ``env_map``:
    the oriented map before scaling (``env = np.float32(env_scale) * env_map``, float32), or
    None when unknown: two lights of one map at other lux share it, so a renderer keeps the
    map's importance sampler (:meth:`grassd.sim.renderer.Renderer._prepare`).
    ``env_irradiance_rgb``: (3,) what ``env`` alone gives on the upward horizontal plane
    (lux-like linear Rec.709), or None when not yet summed; :func:`build_lighting` keeps the
    sum it took for ``ambient_lux``, and a light with another sun (:func:`add_sun`) keeps it.
    """

    env: np.ndarray
    env_scale: float
    sun_direction: np.ndarray | None
    sun_irradiance_rgb: np.ndarray
    ambient_lux: float
    sun_lux: float
    rotation_deg: float = 0.0
    flipped: bool = False
    notes: tuple[str, ...] = field(default=())
    env_map: np.ndarray | None = None
    env_irradiance_rgb: np.ndarray | None = None

    @cached_property
    def horizontal_irradiance_rgb(self) -> np.ndarray:
        """(3,) irradiance on the upward horizontal plane: env + sun * max(0, sun_z) (lux-like)."""
        total = (horizontal_irradiance_rgb(self.env) if self.env_irradiance_rgb is None
                 else self.env_irradiance_rgb)
        if self.sun_direction is not None:
            total = total + self.sun_irradiance_rgb * max(0.0, float(self.sun_direction[2]))
        return _readonly(total)

    @property
    def total_lux(self) -> float:
        """Illuminance on the upward horizontal plane, env plus sun (lux)."""
        return float(self.ambient_lux + self.sun_lux)

    @property
    def env_unscaled(self) -> np.ndarray:
        """The oriented map before scaling (what ``export-scene`` writes as env.exr)."""
        if self.env_map is not None:
            return self.env_map
        return (self.env / np.float32(self.env_scale)).astype(np.float32)


def _check_lux(value, what: str, allow_zero: bool = False) -> float:
    try:
        lux = float(value)
    except (TypeError, ValueError) as exc:
        raise LightingError(f"{what} {value!r} is not a number") from exc
    if not np.isfinite(lux):
        raise LightingError(f"{what} {lux} is not finite")
    if lux < 0.0 or (lux == 0.0 and not allow_zero):
        raise LightingError(f"{what} {lux:g} lx must be {'>= 0' if allow_zero else '> 0'}")
    if lux > MAX_LUX:
        raise LightingError(f"{what} {lux:g} lx exceeds {MAX_LUX:g} lx (brighter than any "
                            "daylight); check the meter's units")
    return lux


def normalised_colour(colour, what: str = "sun colour") -> np.ndarray:
    """A linear Rec.709 colour (3,) scaled to luminance Y = 1."""
    c = np.asarray(colour, dtype=np.float64).reshape(-1)
    if c.shape != (3,) or not np.isfinite(c).all() or (c < 0).any():
        raise LightingError(f"{what} {colour!r} must be three finite non-negative linear "
                            "RGB values")
    y = float(REC709_LUMINANCE @ c)
    if y <= 0.0:
        raise LightingError(f"{what} {colour!r} has zero luminance")
    return c / y


def sun_irradiance_from_lux(sun_lux: float, elevation_deg: float, colour) -> np.ndarray:
    """Perpendicular sun irradiance (3,) from its horizontal lux: ``colour * sun_lux / sin(e)``.

    ``colour`` is normalised to Y = 1, so the luminance of the result is the perpendicular
    illuminance in lux. Raises :class:`LightingError` if that exceeds
    :data:`MAX_SUN_PERPENDICULAR_LUX`.
    """
    s = np.sin(np.radians(elevation_deg))
    perpendicular = sun_lux / s
    if perpendicular > MAX_SUN_PERPENDICULAR_LUX:
        raise LightingError(
            f"sun lux {sun_lux:g} at elevation {elevation_deg:.2f} deg means "
            f"{perpendicular:.0f} lx perpendicular to the sun, more than sunlight can give "
            f"({MAX_SUN_PERPENDICULAR_LUX:g} lx); check the sun reading and elevation"
        )
    return normalised_colour(colour) * perpendicular


def build_lighting(
    hdri,
    ambient_lux: float,
    sun_lux: float | None = None,
    sun_azimuth_deg: float | None = None,
    sun_elevation_deg: float | None = None,
    sun_from_hdri: bool = False,
    rotation_deg: float = 0.0,
    sun_colour=None,
    *,
    flip: bool = False,
    day_of_year: int | None = None,
    max_texels: int = MAX_TEXELS,
) -> Lighting:
    """Scale an HDRI to a lux reading and add a directional sun.

    ``hdri``: a path (.exr/.hdr, read by :func:`grassd.sim.hdri.load_hdri`) or an (H, W, 3)
    array of relative linear Rec.709 radiance; it is oriented by ``flip`` and ``rotation_deg``
    (see :func:`orient_env`). ``max_texels``: the largest map read from a path (refused from
    its header beyond, :class:`~grassd.sim.errors.HdriTooLarge`).

    Without ``sun_from_hdri``: ``ambient_lux`` is the horizontal reading without the sun (meter
    shaded) and the whole map is scaled to it; ``sun_lux`` (horizontal lux of the sun: reading
    with minus reading without) needs ``sun_azimuth_deg`` and ``sun_elevation_deg`` and becomes
    a directional light of perpendicular irradiance ``sun_lux / sin(elevation)`` and colour
    ``sun_colour`` (default :data:`DEFAULT_SUN_COLOUR`).

    With ``sun_from_hdri``: the sun is found in the map (:func:`grassd.sim.sun.find_sun`) and
    the split between map and directional sun follows :func:`grassd.sim.sun.split_sun`
    (``ambient_lux`` is then the TOTAL reading with the sun, unless ``sun_lux`` is also given, in
    which case the two keep their meaning above). The sun colour is the sun region's colour
    unless ``sun_colour`` is given. ``day_of_year`` refines the clear-sky model used there.

    Raises :class:`LightingError` for lux <= 0 or > :data:`MAX_LUX`, a sun at or below the
    horizon, a sun lux without a direction (or the reverse), conflicting sun options.
    """
    ambient = _check_lux(ambient_lux, "ambient lux")
    sun_l = None if sun_lux is None else _check_lux(sun_lux, "sun lux", allow_zero=True)
    if sun_l is not None and ambient + sun_l > MAX_LUX:
        raise LightingError(f"ambient + sun lux = {ambient + sun_l:g} lx exceeds {MAX_LUX:g} lx")
    if (sun_azimuth_deg is None) != (sun_elevation_deg is None):
        raise LightingError("give both the sun azimuth and the sun elevation, or neither")
    if not np.isfinite(rotation_deg):
        raise LightingError(f"HDRI rotation {rotation_deg} deg is not a finite number")

    if isinstance(hdri, str | os.PathLike):
        raw = load_hdri(hdri, max_texels)
    else:
        raw = check_env(hdri, "HDRI array")
    env0 = orient_env(raw, rotation_deg, flip)
    e_map = horizontal_illuminance(env0)
    if e_map <= 0.0:
        raise LightingError("the HDRI gives no light on a horizontal plane (upper hemisphere "
                            "black after orientation)")

    common = dict(rotation_deg=float(rotation_deg), flipped=bool(flip),
                  env_map=_readonly(env0))
    if sun_from_hdri:
        if sun_azimuth_deg is not None:
            raise LightingError("sun_from_hdri takes the sun direction from the map; do not also "
                                "give a sun azimuth/elevation")
        from grassd.sim.sun import split_sun  # sun.py builds on this module's geometry

        split = split_sun(env0, ambient, sun_l, day_of_year=day_of_year)
        base = _env_lighting(env0, split.env_scale, notes=split.notes, **common)
        if split.direction is None or split.sun_lux <= 0.0:
            return base
        colour = split.colour if sun_colour is None else sun_colour
        _, elev = azimuth_elevation_from_direction(split.direction)
        irr = sun_irradiance_from_lux(split.sun_lux, float(elev), colour)
        return replace(base, sun_direction=_readonly(split.direction),
                       sun_irradiance_rgb=_readonly(irr), sun_lux=split.sun_lux)

    if sun_l is not None and sun_azimuth_deg is None:
        raise LightingError("a sun lux was given without a sun direction: give the sun azimuth "
                            "and elevation (or sun_from_hdri)")
    if sun_l is None and sun_azimuth_deg is not None:
        raise LightingError("a sun direction was given without the sun lux (the horizontal "
                            "reading with the sun minus the reading without)")
    base = _env_lighting(env0, ambient / e_map, **common)
    if sun_l is None or sun_l == 0.0:
        return base
    return add_sun(base, sun_l, sun_azimuth_deg, sun_elevation_deg, sun_colour)


def _env_lighting(env0: np.ndarray, k: float, **kwargs) -> Lighting:
    """The light of oriented map ``env0`` scaled by ``k``, without a sun (``kwargs``: the
    other :class:`Lighting` fields); its horizontal irradiance summed once."""
    env = env0 * np.float32(k)
    irr = horizontal_irradiance_rgb(env)
    return Lighting(_readonly(env), k, None, _readonly(np.zeros(3)),
                    float(REC709_LUMINANCE @ irr), 0.0, env_irradiance_rgb=_readonly(irr),
                    **kwargs)


def add_sun(base: Lighting, sun_lux: float, sun_azimuth_deg: float, sun_elevation_deg: float,
            sun_colour=None) -> Lighting:
    """``base``'s map with a directional sun instead of its own (if any): ``sun_lux`` on the
    horizontal plane (lux), from compass azimuth / elevation (deg), colour ``sun_colour``
    (default :data:`DEFAULT_SUN_COLOUR`); what :func:`build_lighting` gives for the same
    readings, without scaling or summing the map again (a time of day moved in ``grassd
    studio`` changes only the sun); a sun lux of 0 gives no sun, as there. Raises
    :class:`LightingError` as :func:`build_lighting` does for a sun lux or direction that
    cannot be."""
    sun_l = _check_lux(sun_lux, "sun lux", allow_zero=True)
    if sun_l == 0.0:
        return base if base.sun_direction is None else replace(
            base, sun_direction=None, sun_irradiance_rgb=_readonly(np.zeros(3)), sun_lux=0.0)
    if base.ambient_lux + sun_l > MAX_LUX:
        raise LightingError(f"ambient + sun lux = {base.ambient_lux + sun_l:g} lx exceeds "
                            f"{MAX_LUX:g} lx")
    az, el = float(sun_azimuth_deg), float(sun_elevation_deg)
    if not (np.isfinite(az) and np.isfinite(el)):
        raise LightingError(f"sun azimuth {az} / elevation {el} must be finite")
    if el <= 0.0:
        raise LightingError(f"sun elevation {el:g} deg is at or below the horizon; a sun that "
                            "is not up gives no direct light (drop the sun options)")
    if el > 90.0:
        raise LightingError(f"sun elevation {el:g} deg exceeds 90 deg")
    direction = direction_from_azimuth_elevation(az % 360.0, el)
    colour = DEFAULT_SUN_COLOUR if sun_colour is None else sun_colour
    irr = sun_irradiance_from_lux(sun_l, el, colour)
    return replace(base, sun_direction=_readonly(direction), sun_irradiance_rgb=_readonly(irr),
                   sun_lux=sun_l)
