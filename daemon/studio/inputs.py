"""What a person sets in the studio, parsed from JSON and checked, with messages that say how to
fix a bad value (the server answers them with a 4xx; the page shows them).

One :class:`Condition` is everything a view depends on: the light (source, lux, sun), the eye,
the pixel's splay, the length shown in the pixel view, the lengths of the characteristic and
whether the tables are the daemon's active ones or recomputed live.
"""

from __future__ import annotations

import datetime as dt
import math
from dataclasses import dataclass
from typing import Any
from zoneinfo import ZoneInfo

from grassd.daemon.errors import DaemonError

#: Lengths (mm) the studio's characteristic is simulated at by default: the reference (0) and
#: every 2 mm up to the longest green length.
DEFAULT_STEP_MM: float = 2.0
#: Most lengths one request may ask for.
MAX_LENGTHS: int = 64
#: Smallest and largest OGCD standard error (CIEDE2000) a request may ask to refine to.
STDERR_BOUNDS: tuple[float, float] = (0.02, 2.0)
#: The studio refines the characteristic until every OGCD standard error is at most this
#: (CIEDE2000): the issue's "converged".
TARGET_STDERR: float = 0.1
#: Largest splay (deg) the slider offers, as the pixel spec allows.
MAX_SPLAY_DEG: float = 45.0


class StudioInputError(DaemonError):
    """A value the studio cannot use; the message names it and says what is accepted."""


@dataclass(frozen=True)
class Sun:
    """The sun of a condition: ``mode`` "none" (shade or night), "measured" (the light source's
    own reading, when it has one), "site" (direction from the site and ``when``, with
    ``lux`` [lx] of horizontal illuminance) or "direction" (``azimuth_deg`` clockwise from
    north and ``elevation_deg``, with ``lux``)."""

    mode: str = "none"
    lux: float = 0.0
    azimuth_deg: float | None = None
    elevation_deg: float | None = None
    when: dt.datetime | None = None


@dataclass(frozen=True)
class Condition:
    """Everything the views depend on. ``viewpoint`` = (h cm, d m, theta deg) as the paper
    writes it; ``ambient_lux`` [lx] the horizontal reading without the sun; ``splay_deg`` the
    blades' outward lean at full length (None: the pixel's own); ``length_mm`` the green
    length the pixel view shows; ``lengths_mm`` the characteristic's lengths (first = the
    reference); ``tables`` "active" (the daemon's table) or "live" (built from this
    characteristic); ``image`` the id of an uploaded picture for the display view, or None;
    ``pixel`` "config" or "fit" (a ``grassd fit`` result given to the studio), None for the
    studio's default."""

    light: str
    ambient_lux: float
    sun: Sun
    viewpoint: tuple[float, float, float]
    splay_deg: float | None
    length_mm: float
    lengths_mm: tuple[float, ...]
    tables: str = "live"
    image: str | None = None
    target_stderr: float = TARGET_STDERR
    pixel: str | None = None


def _finite(x: Any) -> bool:
    """A JSON number that is a finite float (a huge integer is not)."""
    try:
        return math.isfinite(float(x))
    except OverflowError:
        return False


def _number(data: dict[str, Any], key: str, default: float | None = None, *,
            lo: float | None = None, hi: float | None = None, unit: str = "") -> float:
    """``data[key]`` as a finite float within [lo, hi] (StudioInputError otherwise)."""
    v = data.get(key, default)
    if v is None:
        raise StudioInputError(f"{key} is required ({unit})" if unit else f"{key} is required")
    if isinstance(v, bool) or not isinstance(v, int | float) or not _finite(v):
        raise StudioInputError(f"{key} must be a number, got {v!r}")
    v = float(v)
    if (lo is not None and v < lo) or (hi is not None and v > hi):
        raise StudioInputError(f"{key} = {v:g} is out of range: give {lo:g} to {hi:g} {unit}"
                               .rstrip())
    return v


def parse_viewpoint(v: Any) -> tuple[float, float, float]:
    """[h_cm, d_m, theta_deg] checked as :class:`grassd.sim.scene.Viewpoint` does, with the
    studio's words: an eye at or below the display plane is behind the display."""
    from grassd.sim.scene import Viewpoint

    if not isinstance(v, list | tuple) or len(v) != 3 or not all(
            isinstance(x, int | float) and not isinstance(x, bool) for x in v):
        raise StudioInputError(f"viewpoint must be [h_cm, d_m, theta_deg], got {v!r}")
    if not all(_finite(x) for x in v):
        raise StudioInputError(f"viewpoint {v!r} must be finite numbers")
    h, d, theta = (float(x) for x in v)
    if h <= 0:
        raise StudioInputError(f"viewpoint ({h:g}, {d:g}, {theta:g}) is behind the display: "
                               f"the eye must be above its plane (h_cm > 0)")
    try:
        Viewpoint(h, d, theta)
    except Exception as exc:  # SceneError: distance or angle out of range
        raise StudioInputError(str(exc)) from None
    return h, d, theta


def parse_lengths(v: Any, green_max_mm: float) -> tuple[float, ...]:
    """Green lengths (mm): 2..MAX_LENGTHS finite values within 0..green_max_mm."""
    if not isinstance(v, list | tuple) or not 2 <= len(v) <= MAX_LENGTHS:
        raise StudioInputError(f"lengths_mm must be a list of 2 to {MAX_LENGTHS} lengths (mm), "
                               f"the first the reference")
    out = []
    for x in v:
        if isinstance(x, bool) or not isinstance(x, int | float) or not _finite(x):
            raise StudioInputError(f"lengths_mm holds {x!r}: give numbers (mm)")
        if not 0.0 <= x <= green_max_mm:
            raise StudioInputError(f"length {x:g} mm is outside 0..{green_max_mm:g} mm (the "
                                   f"pixel's green_max_mm)")
        out.append(float(x))
    return tuple(out)


def default_lengths(green_max_mm: float) -> tuple[float, ...]:
    """0, 2, 4, ... mm up to ``green_max_mm`` (the studio's characteristic)."""
    n = int(math.floor(green_max_mm / DEFAULT_STEP_MM + 1e-9))
    vals = [i * DEFAULT_STEP_MM for i in range(n + 1)]
    if vals[-1] < green_max_mm:
        vals.append(green_max_mm)
    return tuple(vals)


def parse_sun(data: dict[str, Any], timezone: str) -> Sun:
    """The sun of a request: ``{"mode": ..., "lux": ..., ...}`` under ``data["sun"]``, or the
    bundle manifest's names at top level (``sun_lux``, ``sun_azimuth_deg``,
    ``sun_elevation_deg``); ``when`` (ISO 8601, naive = the site's ``timezone``) for mode
    "site"."""
    from grassd.sim.lighting import MAX_LUX

    if "sun" not in data:
        if data.get("sun_lux") is None:
            if data.get("sun_azimuth_deg") is not None:
                raise StudioInputError("sun_azimuth_deg needs sun_lux (the sun's horizontal lux)")
            return Sun()
        lux = _number(data, "sun_lux", lo=0.0, hi=MAX_LUX, unit="lx")
        if lux == 0:
            return Sun()
        if (data.get("sun_azimuth_deg") is None) != (data.get("sun_elevation_deg") is None):
            raise StudioInputError("give both sun_azimuth_deg and sun_elevation_deg, or neither")
        if data.get("sun_azimuth_deg") is None:
            raise StudioInputError("sun_lux needs sun_azimuth_deg and sun_elevation_deg (the "
                                   "sun's direction, as in a bundle manifest)")
        return Sun("direction", lux,
                   _number(data, "sun_azimuth_deg", lo=0.0, hi=360.0, unit="deg"),
                   _number(data, "sun_elevation_deg", lo=0.0, hi=90.0, unit="deg"))
    sun = data["sun"]
    if not isinstance(sun, dict):
        raise StudioInputError("sun must be an object with a mode")
    mode = sun.get("mode", "none")
    if mode == "none":
        return Sun()
    if mode == "measured":
        return Sun("measured")
    if mode not in ("site", "direction"):
        raise StudioInputError(f"sun mode {mode!r} is not one of none, measured, site, "
                               f"direction")
    lux = _number(sun, "lux", lo=0.0, hi=MAX_LUX, unit="lx")
    if mode == "site":
        when = sun.get("when")
        try:
            moment = dt.datetime.fromisoformat(str(when))
        except ValueError:
            raise StudioInputError(f"sun time {when!r} is not an ISO 8601 time, e.g. "
                                   f"2026-11-27T17:00") from None
        if moment.tzinfo is None:
            moment = moment.replace(tzinfo=ZoneInfo(timezone))
        return Sun("site", lux, when=moment)
    return Sun("direction", lux, _number(sun, "azimuth_deg", lo=0.0, hi=360.0, unit="deg"),
               _number(sun, "elevation_deg", lo=0.0, hi=90.0, unit="deg"))


def parse_condition(data: Any, *, green_max_mm: float, timezone: str, lights: set[str],
                    default_light: str) -> Condition:
    """A :class:`Condition` from a request's JSON object (StudioInputError naming the first
    bad value). ``lights``: the names of the light sources the studio has."""
    from grassd.sim.lighting import MAX_LUX

    if not isinstance(data, dict):
        raise StudioInputError("send a JSON object")
    light = data.get("light", default_light)
    if not isinstance(light, str) or light not in lights:
        raise StudioInputError(f"light {light!r} is not one of the studio's: "
                               + ", ".join(sorted(lights)))
    lux = _number(data, "ambient_lux", lo=1e-3, hi=MAX_LUX, unit="lx")
    splay = data.get("splay_deg")
    if splay is not None:
        splay = _number(data, "splay_deg", lo=0.0, hi=MAX_SPLAY_DEG, unit="deg")
    lengths = (parse_lengths(data["lengths_mm"], green_max_mm) if "lengths_mm" in data
               else default_lengths(green_max_mm))
    tables = data.get("tables", "live")
    if tables not in ("live", "active"):
        raise StudioInputError(f"tables must be \"live\" or \"active\", got {tables!r}")
    image = data.get("image")
    if image is not None and not isinstance(image, str):
        raise StudioInputError("image must be the id an upload returned")
    pixel = data.get("pixel")
    if pixel is not None and pixel not in ("config", "fit"):
        raise StudioInputError(f"pixel must be \"config\" or \"fit\", got {pixel!r}")
    target = _number(data, "target_stderr", TARGET_STDERR, lo=STDERR_BOUNDS[0],
                     hi=STDERR_BOUNDS[1], unit="dE00")
    return Condition(
        light=light, ambient_lux=lux, sun=parse_sun(data, timezone),
        viewpoint=parse_viewpoint(data.get("viewpoint")), splay_deg=splay,
        length_mm=_number(data, "length_mm", green_max_mm / 2, lo=0.0, hi=green_max_mm,
                          unit="mm"),
        lengths_mm=lengths, tables=tables, image=image, target_stderr=target, pixel=pixel)
