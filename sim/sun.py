"""The sun: its position from place and time, finding it in an HDRI, restoring a clipped sun.

Directions follow :mod:`grassd.sim.lighting` (ENU, z up; compass azimuth clockwise from north).

Clipped-sun restoration (:func:`split_sun`, used by ``build_lighting(sun_from_hdri=True)``)
------------------------------------------------------------------------------------------
Panoramas usually clip the sun (the shared ones were clamped at 32000 before compression), so
the map underrates the direct light relative to the sky. Given the map (oriented) and a lux
reading, the rule is:

1. Find the sun region S (:func:`sun_mask`). With no compact sun above the horizon, the whole
   map is scaled to the reading (overcast sky or sun outside the view), no directional sun.
2. Split the map's horizontal illuminance into sun and sky, ``E_map = E_S + E_sky`` (exact
   integrals of :func:`grassd.sim.lighting.horizontal_illuminance`), map sun fraction
   ``f_map = E_S / E_map``.
3. Target sun fraction f of the total reading E_tot:

   - two readings (``sun_lux`` given; ``ambient_lux`` = reading with the sun shaded, so
     E_tot = ambient + sun): measured ``f = sun_lux / E_tot``; if that is below f_map the
     map's sun is already too bright, which cannot be undone without editing the map: f =
     f_map is used and a note says so.
   - one reading (``ambient_lux`` = TOTAL with the sun): ``f = max(f_map, f_model)`` with
     f_model the direct fraction of the Erbs et al. (1982) decomposition
     (``pvlib.irradiance.erbs``) of the global irradiance E_tot / :data:`GLOBAL_EFFICACY_LM_W`
     at the sun's zenith angle. A map whose sun already holds at least that share is taken as
     unclipped and trusted as it is.

4. The sky keeps its shape and gets ``(1 - f) E_tot``: ``k = (1 - f) E_tot / E_sky``; nothing
   is removed from the map (its clipped sun stays, scaled by k); the deficit
   ``E_tot f - k E_S >= 0`` becomes a directional sun at the region's direction, colour of the
   region. When f = f_map the deficit is 0 and the map is simply scaled to the total.
"""

from __future__ import annotations

import datetime as _dt
import logging
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
from scipy import ndimage

from grassd.sim.errors import LightingError
from grassd.sim.hdri import REC709_LUMINANCE
from grassd.sim.lighting import (
    DEFAULT_SUN_COLOUR,
    MAX_SUN_PERPENDICULAR_LUX,
    azimuth_elevation_from_direction,
    direction_from_azimuth_elevation,
    horizontal_cosine_weights,
    normalised_colour,
    texel_solid_angles,
    uv_to_direction,
)

__all__ = [
    "GLOBAL_EFFICACY_LM_W",
    "MAX_SUN_SOLID_ANGLE_SR",
    "MIN_SUN_CONTRAST",
    "SUN_DIRECTION_TOLERANCE_DEG",
    "SUN_THRESHOLD_FRACTION",
    "SunRegion",
    "SunSplit",
    "check_sun_reading",
    "clear_sky_direct_fraction",
    "find_sun",
    "split_sun",
    "sun_mask",
    "sun_position",
]

log = logging.getLogger(__name__)

#: The sun region is the connected set of texels at least this fraction of the peak luminance.
SUN_THRESHOLD_FRACTION: float = 0.1
#: Largest solid angle accepted as a sun (sr). The solar disc is 6.8e-5 sr; 2e-3 sr (a cone of
#: 1.45 deg half-angle) admits a blurred/bloomed disc in a 1k map but not a window or softbox.
MAX_SUN_SOLID_ANGLE_SR: float = 2e-3
#: The peak must be at least this many times the median luminance above the horizon.
MIN_SUN_CONTRAST: float = 100.0
#: Luminous efficacy of global daylight, lm/W, to turn a lux reading into W/m^2 for the Erbs
#: model (clear-sky global efficacy is about 105-120 lm/W; Littlefair 1985, Perez et al. 1990).
GLOBAL_EFFICACY_LM_W: float = 110.0
#: Extraterrestrial solar illuminance perpendicular to the sun, lux (solar illuminance
#: constant, about 128-133 klux; the upper value).
EXTRATERRESTRIAL_LUX: float = 133_000.0
#: Lowest sun elevation (deg) at which a restored directional sun is added.
MIN_SUN_ELEVATION_DEG: float = 1.0
#: Largest angle (deg) between a reported sun direction and the sun's computed position at the
#: site and time that is still taken as the same sun. The sun moves about 15 deg an hour, so a
#: camera clock an hour off (a time-zone error) or a wrong site lands far outside it, while
#: levelling a camera and reading a sun off a panorama stay within a few degrees.
SUN_DIRECTION_TOLERANCE_DEG: float = 5.0


# --------------------------------------------------------------------------- sun position


def sun_position(latitude_deg: float, longitude_deg: float,
                 when: _dt.datetime) -> tuple[float, float]:
    """Compass azimuth (deg from north, clockwise) and apparent elevation (deg, refraction
    included) of the sun's centre, by the NREL SPA algorithm (Reda & Andreas 2004) in
    ``pvlib.solarposition`` (method ``nrel_numpy``). ``when`` must be timezone-aware;
    longitude positive east."""
    if not (np.isfinite(latitude_deg) and -90.0 <= latitude_deg <= 90.0):
        raise LightingError(f"latitude {latitude_deg} must be within -90..90 deg")
    if not (np.isfinite(longitude_deg) and -180.0 <= longitude_deg <= 180.0):
        raise LightingError(f"longitude {longitude_deg} must be within -180..180 deg (east +)")
    if not isinstance(when, _dt.datetime):
        raise LightingError(f"sun position needs a datetime, got {type(when).__name__}")
    if when.tzinfo is None or when.utcoffset() is None:
        raise LightingError(f"time {when.isoformat()} has no timezone; give one (e.g. +00:00)")
    import pandas as pd
    from pvlib import solarposition

    times = pd.DatetimeIndex([pd.Timestamp(when)])
    pos = solarposition.get_solarposition(times, latitude_deg, longitude_deg,
                                          method="nrel_numpy")
    return float(pos["azimuth"].iloc[0]), float(pos["apparent_elevation"].iloc[0])


def check_sun_reading(sun_lux: float | None, azimuth_deg: float | None = None,
                      elevation_deg: float | None = None, *,
                      latitude_deg: float | None = None, longitude_deg: float | None = None,
                      when: _dt.datetime | None = None) -> tuple[float, float] | None:
    """Check that a sun reading can be real; return the sun's (azimuth, elevation) in degrees.

    ``sun_lux`` is the sun's share of a horizontal lux meter (lux with the sun minus lux with it
    shaded); ``azimuth_deg`` (compass, clockwise from north) and ``elevation_deg`` are its
    reported direction, if any. Where the site (``latitude_deg``, ``longitude_deg``, east +) and
    a timezone-aware ``when`` are known, the sun's position there and then
    (:func:`sun_position`) is the expected direction. Raises :class:`LightingError` when:

    - the sun gives light (``sun_lux > 0``) from at or below the horizon, reported or computed;
    - ``sun_lux / sin(elevation)`` exceeds :data:`MAX_SUN_PERPENDICULAR_LUX` (more than
      sunlight gives perpendicular to the sun);
    - a reported direction lies more than :data:`SUN_DIRECTION_TOLERANCE_DEG` from the computed
      one (a camera clock or time zone off, or a wrong site).

    Returns None when there is no sun light (``sun_lux`` None or 0) or no direction is known.

    >>> check_sun_reading(30000.0, 180.0, 40.0)
    (180.0, 40.0)
    >>> check_sun_reading(40000.0, 180.0, -5.0)  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    grassd.sim.errors.LightingError: sun lux 40000 lx from elevation -5.0 deg: a sun at or ...
    """
    if sun_lux is None or sun_lux == 0:
        return None
    site_known = latitude_deg is not None and longitude_deg is not None and when is not None
    expected = sun_position(latitude_deg, longitude_deg, when) if site_known else None
    if azimuth_deg is None or elevation_deg is None:
        if expected is None:
            return None
        azimuth_deg, elevation_deg = expected
        if elevation_deg <= 0.0:
            raise LightingError(
                f"sun lux {sun_lux:g} lx at {when.isoformat()}, but the sun is "
                f"{-elevation_deg:.1f} deg below the horizon at the site (latitude "
                f"{latitude_deg:g}, longitude {longitude_deg:g}) then; check the time and time "
                f"zone of the capture, the sun reading, and [site] in the config")
    elif elevation_deg <= 0.0:
        raise LightingError(
            f"sun lux {sun_lux:g} lx from elevation {elevation_deg:.1f} deg: a sun at or below "
            f"the horizon gives no light; check the sun reading and its direction")
    perpendicular = sun_lux / np.sin(np.radians(elevation_deg))
    if perpendicular > MAX_SUN_PERPENDICULAR_LUX:
        raise LightingError(
            f"sun lux {sun_lux:g} lx at elevation {elevation_deg:.1f} deg means "
            f"{perpendicular:.0f} lx perpendicular to the sun, more than sunlight can give "
            f"({MAX_SUN_PERPENDICULAR_LUX:g} lx); check the sun reading and its elevation")
    if expected is not None and (azimuth_deg, elevation_deg) != expected:
        cos = float(direction_from_azimuth_elevation(azimuth_deg, elevation_deg)
                    @ direction_from_azimuth_elevation(*expected))
        off = float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))
        if off > SUN_DIRECTION_TOLERANCE_DEG:
            raise LightingError(
                f"sun direction (azimuth {azimuth_deg:.1f}, elevation {elevation_deg:.1f} deg) "
                f"is {off:.1f} deg from where the sun stands at the site (latitude "
                f"{latitude_deg:g}, longitude {longitude_deg:g}) at {when.isoformat()}: azimuth "
                f"{expected[0]:.1f}, elevation {expected[1]:.1f} deg (tolerance "
                f"{SUN_DIRECTION_TOLERANCE_DEG:g} deg); check the capture's clock and time "
                f"zone, and [site] in the config")
    return float(azimuth_deg), float(elevation_deg)


def clear_sky_direct_fraction(global_lux: float, elevation_deg: float,
                              day_of_year: int | None = None) -> float:
    """Share of the horizontal illuminance that comes straight from the sun, by the Erbs et al.
    (1982) decomposition (``pvlib.irradiance.erbs``) of global horizontal irradiance
    ``global_lux / GLOBAL_EFFICACY_LM_W`` (W/m^2) at zenith 90 - elevation. ``day_of_year``
    (default 80, near the equinox, where the extraterrestrial irradiance is within 1 % of its
    mean) sets the extraterrestrial irradiance. 0 below 3 deg elevation (the model's limit)."""
    from pvlib import irradiance

    if elevation_deg <= 3.0:
        return 0.0
    ghi = float(global_lux) / GLOBAL_EFFICACY_LM_W
    out = irradiance.erbs(ghi, 90.0 - float(elevation_deg),
                          80 if day_of_year is None else int(day_of_year))
    dhi = float(np.asarray(out["dhi"]))
    return float(np.clip(1.0 - dhi / ghi, 0.0, 1.0))


# -------------------------------------------------------------------------- sun in a map


class SunRegion(NamedTuple):
    """A sun found in a map: unit ``direction`` (3,) towards the luminance-weighted centroid,
    ``solid_angle_sr`` of the region, ``mean_radiance_rgb`` (3,) its solid-angle mean radiance
    (map units)."""

    direction: np.ndarray
    solid_angle_sr: float
    mean_radiance_rgb: np.ndarray


def sun_mask(env: np.ndarray) -> np.ndarray | None:
    """Boolean (H, W) mask of the sun in a map, or None if there is no compact sun.

    The peak is the brightest texel (luminance) in the rows above the horizon; the region is
    the 8-connected component (wrapping around u) of texels with luminance >=
    :data:`SUN_THRESHOLD_FRACTION` x peak that holds it. Accepted if the peak is at least
    :data:`MIN_SUN_CONTRAST` x the median luminance above the horizon, the region's solid angle
    is at most :data:`MAX_SUN_SOLID_ANGLE_SR` and its centroid is above the horizon.
    """
    rad = np.asarray(env)
    h, w = rad.shape[:2]
    lum = rad.astype(np.float64) @ REC709_LUMINANCE
    upper = h // 2  # rows entirely above the horizon
    top = lum[:upper]
    flat = int(np.argmax(top))
    r0, c0 = divmod(flat, w)
    peak = float(top[r0, c0])
    if peak <= 0.0 or peak < MIN_SUN_CONTRAST * float(np.median(top)):
        return None
    shift = w // 2 - c0  # put the peak mid-image so the component never straddles the seam
    rolled = np.roll(lum, shift, axis=1) >= SUN_THRESHOLD_FRACTION * peak
    labels, _ = ndimage.label(rolled, structure=np.ones((3, 3), bool))
    mask = np.roll(labels == labels[r0, w // 2], -shift, axis=1)
    omega = texel_solid_angles(h, w)
    if float((mask * omega[:, None]).sum()) > MAX_SUN_SOLID_ANGLE_SR:
        return None
    if _centroid(rad, mask)[2] <= 0.0:
        return None
    return mask


def _centroid(rad: np.ndarray, mask: np.ndarray) -> np.ndarray:
    h, w = mask.shape
    rows, cols = np.nonzero(mask)
    omega = texel_solid_angles(h, w)[rows]
    weight = (rad[rows, cols].astype(np.float64) @ REC709_LUMINANCE) * omega
    dirs = uv_to_direction((cols + 0.5) / w, (rows + 0.5) / h)
    d = (dirs * weight[:, None]).sum(axis=0)
    return d / np.linalg.norm(d)


def find_sun(env: np.ndarray) -> SunRegion | None:
    """The brightest compact region above the horizon of an (H, W, 3) map (see
    :func:`sun_mask`), or None."""
    mask = sun_mask(env)
    if mask is None:
        return None
    rad = np.asarray(env)
    h, w = mask.shape
    rows, cols = np.nonzero(mask)
    omega = texel_solid_angles(h, w)[rows]
    solid = float(omega.sum())
    mean = (rad[rows, cols].astype(np.float64) * omega[:, None]).sum(axis=0) / solid
    return SunRegion(_centroid(rad, mask), solid, mean)


# ----------------------------------------------------------------------- clipped sun


@dataclass(frozen=True)
class SunSplit:
    """Outcome of :func:`split_sun`: map scale ``env_scale``; directional sun ``direction``
    (None if none), its horizontal ``sun_lux`` and ``colour`` (Y = 1); the map's sun share
    ``map_fraction`` and the target share ``target_fraction``; ``notes`` for the user."""

    env_scale: float
    direction: np.ndarray | None
    sun_lux: float
    colour: np.ndarray
    map_fraction: float
    target_fraction: float
    notes: tuple[str, ...] = field(default=())


def split_sun(env: np.ndarray, ambient_lux: float, sun_lux: float | None = None,
              day_of_year: int | None = None) -> SunSplit:
    """Split a lux reading between an (oriented, unscaled) map and a directional sun found in
    it, by the rule in the module docstring. ``ambient_lux`` is the total reading with the
    sun when ``sun_lux`` is None, else the reading with the sun shaded. Lux throughout."""
    rad = np.asarray(env)
    h, w = rad.shape[:2]
    lum = rad.astype(np.float64) @ REC709_LUMINANCE
    cw = horizontal_cosine_weights(h, w)
    e_map = float((lum * cw[:, None]).sum())
    total = float(ambient_lux) + (0.0 if sun_lux is None else float(sun_lux))
    mask = sun_mask(rad)
    if mask is None:
        if sun_lux:
            raise LightingError("a sun lux was given but no compact sun is visible in the HDRI; "
                                "give the sun azimuth and elevation instead of sun_from_hdri")
        note = "no compact sun found in the HDRI: the whole map is scaled to the reading"
        log.warning(note)
        return SunSplit(total / e_map, None, 0.0, DEFAULT_SUN_COLOUR.copy(), 0.0, 0.0, (note,))
    region = find_sun(rad)
    assert region is not None
    e_sun = float((lum * cw[:, None] * mask).sum())
    e_sky = e_map - e_sun
    if e_sky <= 0.0:
        raise LightingError("the HDRI holds no sky light outside the sun region; cannot split "
                            "the reading between sky and sun")
    f_map = e_sun / e_map
    _, elev = azimuth_elevation_from_direction(region.direction)
    elev = float(elev)
    notes: list[str] = []
    if sun_lux is not None:
        f_target = float(sun_lux) / total
        if f_target < f_map:
            notes.append(f"the HDRI's sun gives {100 * f_map:.1f}% of its light, more than the "
                         f"measured {100 * f_target:.1f}%; the map is scaled as it is")
    else:
        f_target = clear_sky_direct_fraction(total, elev, day_of_year)
        ceiling = EXTRATERRESTRIAL_LUX * np.sin(np.radians(max(elev, 0.0)))
        if total > ceiling:
            notes.append(f"the reading {total:g} lx exceeds the {ceiling:.0f} lx sunlight "
                         f"gives above the atmosphere at the found sun's {elev:.1f} deg "
                         "elevation: check the lux reading and the HDRI orientation")
    f = max(f_map, f_target)
    k = (1.0 - f) * total / e_sky
    deficit = max(0.0, f * total - k * e_sun)
    try:
        colour = normalised_colour(region.mean_radiance_rgb, "sun region colour")
    except LightingError:
        colour = DEFAULT_SUN_COLOUR.copy()
    if elev < MIN_SUN_ELEVATION_DEG or deficit <= 1e-9 * total:
        if deficit > 1e-9 * total:
            notes.append(f"sun at {elev:.2f} deg elevation is too low for a directional light; "
                         "its deficit is ignored")
        k = total / e_map
        notes.append(f"map sun share {100 * f_map:.1f}%: map scaled to {total:g} lx, no "
                     "directional sun added")
        for n in notes:
            log.info(n)
        return SunSplit(k, None, 0.0, colour, f_map, f_target, tuple(notes))
    notes.append(f"map sun share {100 * f_map:.1f}% < target {100 * f:.1f}%: sun clipped; "
                 f"adding {deficit:.0f} lx (horizontal) of directional sun at "
                 f"{elev:.1f} deg elevation")
    for n in notes:
        log.info(n)
    return SunSplit(k, region.direction, deficit, colour, f_map, f_target, tuple(notes))
