"""What a person sets in the studio, parsed from JSON and checked, with messages that say how to
fix a bad value (the server answers them with a 4xx; the page shows them).

One :class:`Condition` is everything a view depends on: the light (source, lux, sun), the eye,
the pixel's splay, the length shown in the pixel view, the lengths of the characteristic and
whether the tables are the daemon's active ones or recomputed live.
"""

from __future__ import annotations

import datetime as dt
import math
import reprlib
from dataclasses import dataclass
from itertools import pairwise
from typing import TypeAlias, TypeGuard
from zoneinfo import ZoneInfo

from grassd.daemon.core.errors import DaemonError

#: Lengths (mm) the studio's characteristic is simulated at by default: the reference (0) and
#: every 2 mm up to the longest green length.
DEFAULT_STEP_MM: float = 2.0
#: Most lengths one request may ask for.
MAX_LENGTHS: int = 64
#: Smallest and largest OGCD standard error (CIEDE2000) a request may ask to refine to.
STDERR_BOUNDS: tuple[float, float] = (0.02, 2.0)
#: The studio refines the characteristic until every OGCD standard error is at most this
#: (CIEDE2000): what the studio calls "converged".
TARGET_STDERR: float = 0.1
#: Largest splay (deg) the slider offers, as the pixel spec allows.
MAX_SPLAY_DEG: float = 45.0


#: A value as :func:`json.loads` gives it, before it is checked.
JsonValue: TypeAlias = None | bool | int | float | str | list["JsonValue"] | dict[str, "JsonValue"]


class StudioInputError(DaemonError):
    """A value the studio cannot use; the message names it and says what is accepted."""


@dataclass(frozen=True)
class Sun:
    """The sun of a condition: ``mode`` "none" (shade or night), "measured" (the light source's
    own reading, when it has one), "site" (direction from the site and ``when``, with
    ``lux`` [lx] of horizontal illuminance) or "direction" (``azimuth_deg`` clockwise from
    north and ``elevation_deg``, with ``lux``). A sun of 0 lx is parsed as mode "none"."""

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


#: The keys a condition may hold (what the page and the API send); any other is refused, so a
#: misspelt key is said rather than silently ignored.
CONDITION_KEYS: tuple[str, ...] = (
    "light", "ambient_lux", "sun", "sun_lux", "sun_azimuth_deg", "sun_elevation_deg",
    "viewpoint", "splay_deg", "length_mm", "lengths_mm", "tables", "image", "target_stderr",
    "pixel")
#: The sun as a bundle manifest names it, at a condition's top level: lux [lx], compass
#: azimuth and elevation [deg]; all three, or ``sun_lux`` 0 alone (no sun).
MANIFEST_SUN_KEYS: tuple[str, ...] = ("sun_lux", "sun_azimuth_deg", "sun_elevation_deg")
#: The keys of a condition's ``sun`` object for each of its modes (each one required).
SUN_MODE_KEYS: dict[str, tuple[str, ...]] = {
    "none": ("mode",), "measured": ("mode",), "site": ("mode", "lux", "when"),
    "direction": ("mode", "lux", "azimuth_deg", "elevation_deg")}
#: Most characters of a person's value echoed in a message (longer ones are cut).
MAX_SHOWN_CHARS: int = 40

_SHOWN = reprlib.Repr()
_SHOWN.maxstring = _SHOWN.maxlong = _SHOWN.maxother = MAX_SHOWN_CHARS
_SHOWN.maxlist = _SHOWN.maxtuple = _SHOWN.maxdict = 6


def _shown(v: JsonValue) -> str:
    """``repr(v)`` cut to about :data:`MAX_SHOWN_CHARS` characters, for a message that echoes
    a person's value (a 300-digit number or a long string does not fill the page; JSON gives
    no integer longer than Python writes out: the server refuses those as not JSON)."""
    text = _SHOWN.repr(v)
    return text if len(text) <= MAX_SHOWN_CHARS else text[:MAX_SHOWN_CHARS - 3] + "..."


def _is_number(x: JsonValue) -> TypeGuard[int | float]:
    """A JSON number (a bool is not one)."""
    return isinstance(x, int | float) and not isinstance(x, bool)


def _real(x: JsonValue) -> float | None:
    """A JSON number as a float: an integer too large for one is +-inf (out of every range);
    None for anything else (a string, a bool, NaN)."""
    if not _is_number(x):
        return None
    try:
        f = float(x)
    except OverflowError:
        return math.inf if x > 0 else -math.inf
    return None if math.isnan(f) else f


def _finite(x: JsonValue) -> bool:
    """A JSON number that is a finite float (a huge integer is not)."""
    f = _real(x)
    return f is not None and math.isfinite(f)


def _as_number(v: JsonValue) -> str:
    """A number for a message: ``:g`` where it is a finite float, else cut (:func:`_shown`)."""
    f = _real(v)
    return f"{f:g}" if f is not None and math.isfinite(f) else _shown(v)


def _given(data: dict[str, JsonValue]) -> dict[str, JsonValue]:
    """``data`` without its nulls: a JSON null means the same as the key left out."""
    return {k: v for k, v in data.items() if v is not None}


def _number(data: dict[str, JsonValue], key: str, default: float | None = None, *,
            lo: float, hi: float, unit: str = "", above: bool = False) -> float:
    """``data[key]`` (null or missing: ``default``, required where that is None) as a finite
    float within [lo, hi], or (lo, hi] where ``above`` (StudioInputError otherwise)."""
    v = data.get(key)
    if v is None:
        v = default
    if v is None:
        raise StudioInputError(f"{key} is required ({unit})" if unit else f"{key} is required")
    f = _real(v)
    if f is None:
        raise StudioInputError(f"{key} must be a number{f' ({unit})' if unit else ''}, "
                               f"got {_shown(v)}")
    if (f <= lo if above else f < lo) or not f <= hi:
        span = f"more than {lo:g}, up to {hi:g}" if above else f"{lo:g} to {hi:g}"
        raise StudioInputError(f"{key} = {_as_number(v)} is out of range: give {span} {unit}"
                               .rstrip())
    return f


def parse_viewpoint(v: JsonValue) -> tuple[float, float, float]:
    """[h_cm, d_m, theta_deg] checked as :class:`grassd.sim.scene.Viewpoint` does, with the
    studio's words: an eye at or below the display plane is behind the display."""
    from grassd.sim.scene import Viewpoint

    if v is None:
        raise StudioInputError("viewpoint is required: [h_cm, d_m, theta_deg] (cm, m, deg), "
                               "e.g. [170, 2, 0]")
    if not isinstance(v, list | tuple) or len(v) != 3 or not all(_is_number(x) for x in v):
        raise StudioInputError(f"viewpoint must be [h_cm, d_m, theta_deg] (cm, m, deg), e.g. "
                               f"[170, 2, 0]; got {_shown(v)}")
    hdt: list[float] = []
    for name, x, unit in zip(("h_cm", "d_m", "theta_deg"), v, ("cm", "m", "deg"), strict=True):
        f = _real(x)
        if f is None or not math.isfinite(f):
            raise StudioInputError(f"viewpoint {name} = {_as_number(x)} must be a finite "
                                   f"number ({unit})")
        hdt.append(f)
    h, d, theta = hdt
    if h <= 0:
        raise StudioInputError(f"viewpoint ({h:g}, {d:g}, {theta:g}) is behind the display: "
                               f"the eye must be above its plane (h_cm > 0)")
    try:
        Viewpoint(h, d, theta)
    except Exception as exc:  # SceneError: distance or angle out of range
        raise StudioInputError(str(exc)) from None
    return h, d, theta


def parse_lengths(v: JsonValue, green_max_mm: float) -> tuple[float, ...]:
    """Green lengths (mm): 2..MAX_LENGTHS values within 0..green_max_mm, strictly increasing
    (the first is the reference, the shortest grass)."""
    if not isinstance(v, list | tuple) or not 2 <= len(v) <= MAX_LENGTHS:
        raise StudioInputError(f"lengths_mm must be a list of 2 to {MAX_LENGTHS} lengths (mm), "
                               f"the first the reference; got {_shown(v)}")
    out: list[float] = []
    for x in v:
        f = _real(x)
        if f is None:
            raise StudioInputError(f"lengths_mm holds {_shown(x)}: give numbers (mm)")
        if not 0.0 <= f <= green_max_mm:
            raise StudioInputError(f"length {_as_number(x)} mm is outside 0..{green_max_mm:g} mm "
                                   f"(the pixel's green_max_mm)")
        out.append(f)
    if any(b <= a for a, b in pairwise(out)):
        raise StudioInputError(f"lengths_mm must increase strictly (the first is the "
                               f"reference, the shortest grass); got {_shown(v)}")
    return tuple(out)


def default_lengths(green_max_mm: float) -> tuple[float, ...]:
    """0, 2, 4, ... mm up to ``green_max_mm`` (the studio's characteristic)."""
    n = int(math.floor(green_max_mm / DEFAULT_STEP_MM + 1e-9))
    vals = [i * DEFAULT_STEP_MM for i in range(n + 1)]
    if vals[-1] < green_max_mm:
        vals.append(green_max_mm)
    return tuple(vals)


def _needs(given: list[str], missing: list[str]) -> StudioInputError:
    """The error for manifest sun keys ``given`` without the ``missing`` ones."""
    verb = "needs" if len(given) == 1 else "need"
    return StudioInputError(
        f"{' and '.join(given)} {verb} {' and '.join(missing)}: give the sun as a bundle "
        f"manifest does, sun_lux (lx) with sun_azimuth_deg and sun_elevation_deg (deg), or "
        f"sun_lux 0 alone for no sun")


def _direction(data: dict[str, JsonValue], azimuth: str, elevation: str,
               lux: float) -> tuple[float, float]:
    """The sun's compass azimuth and elevation (deg) under the keys ``azimuth`` and
    ``elevation`` of ``data``. A sun that gives light (``lux`` > 0) is above the horizon:
    elevation more than 0, up to 90; without light (lux 0) any elevation -90 to 90 a reading
    may have (a bundle manifest's range), checked all the same."""
    az = _number(data, azimuth, lo=0.0, hi=360.0, unit="deg")
    if lux > 0:
        return az, _number(data, elevation, lo=0.0, hi=90.0, unit="deg", above=True)
    return az, _number(data, elevation, lo=-90.0, hi=90.0, unit="deg")


def parse_sun(data: dict[str, JsonValue], timezone: str) -> Sun:
    """The sun of a request: ``{"mode": ..., ...}`` under ``data["sun"]`` with the keys of
    :data:`SUN_MODE_KEYS` (``lux`` [lx]; ``when`` ISO 8601, naive = the site's ``timezone``;
    ``azimuth_deg``, ``elevation_deg``), or the bundle manifest's names at top level
    (:data:`MANIFEST_SUN_KEYS`), not both. A null is a key left out; a lux of 0 is no sun
    (mode "none"), its other values checked all the same."""
    from grassd.sim.lighting import MAX_LUX

    data = _given(data)
    manifest = [k for k in MANIFEST_SUN_KEYS if k in data]
    if "sun" in data:
        if manifest:
            raise StudioInputError("give the sun either as `sun` or as sun_lux/sun_azimuth_deg/"
                                   f"sun_elevation_deg, not both (got sun and "
                                   f"{', '.join(manifest)})")
        return _sun_object(data["sun"], timezone)
    if not manifest:
        return Sun()
    lux = _number(data, "sun_lux", lo=0.0, hi=MAX_LUX, unit="lx") if "sun_lux" in data else None
    missing = [k for k in MANIFEST_SUN_KEYS if k not in data]
    if lux == 0 and missing == ["sun_azimuth_deg", "sun_elevation_deg"]:
        return Sun()  # a shaded reading: no sun, and no direction needed
    if missing:
        raise _needs(manifest, missing)
    az, el = _direction(data, "sun_azimuth_deg", "sun_elevation_deg", lux)
    return Sun("direction", lux, az, el) if lux > 0 else Sun()


def _sun_object(sun: JsonValue, timezone: str) -> Sun:
    """The sun given as an object (see :func:`parse_sun`)."""
    from grassd.sim.lighting import MAX_LUX

    example = '{"mode": "site", "lux": 40000, "when": "2026-11-27T15:00"}'
    if not isinstance(sun, dict):
        raise StudioInputError(f"sun must be an object with a mode, e.g. {example}; got "
                               f"{_shown(sun)}")
    sun = _given(sun)
    mode = sun.get("mode", "none")
    if not isinstance(mode, str) or mode not in SUN_MODE_KEYS:
        raise StudioInputError(f"sun mode {_shown(mode)} is not one of "
                               + ", ".join(SUN_MODE_KEYS))
    keys = SUN_MODE_KEYS[mode]
    extra = [_shown(k) for k in sun if k not in keys]
    if extra:
        raise StudioInputError(f"sun mode {mode} does not take {', '.join(extra[:5])}: it takes "
                               + ", ".join(keys))
    if mode == "none":
        return Sun()
    if mode == "measured":
        return Sun("measured")
    lux = _number(sun, "lux", lo=0.0, hi=MAX_LUX, unit="lx")
    if mode == "site":
        when = sun.get("when")
        if when is None:
            raise StudioInputError(f"sun mode site needs `when`, the time at the site (ISO 8601; "
                                   f"without a zone, the site's), e.g. {example}")
        try:
            moment = dt.datetime.fromisoformat(when if isinstance(when, str) else "")
        except ValueError:
            raise StudioInputError(f"sun time {_shown(when)} is not an ISO 8601 time, e.g. "
                                   f"2026-11-27T17:00") from None
        if moment.tzinfo is None:
            moment = moment.replace(tzinfo=ZoneInfo(timezone))
        return Sun("site", lux, when=moment) if lux > 0 else Sun()
    missing = [k for k in ("azimuth_deg", "elevation_deg") if k not in sun]
    if missing:
        raise StudioInputError(f"sun mode direction needs {' and '.join(missing)} (deg), e.g. "
                               '{"mode": "direction", "lux": 40000, "azimuth_deg": 200, '
                               '"elevation_deg": 35}')
    az, el = _direction(sun, "azimuth_deg", "elevation_deg", lux)
    return Sun("direction", lux, az, el) if lux > 0 else Sun()


def parse_condition(data: JsonValue, *, green_max_mm: float, timezone: str, lights: set[str],
                    default_light: str) -> Condition:
    """A :class:`Condition` from a request's JSON object (StudioInputError naming the first
    bad value). ``lights``: the names of the light sources the studio has. Only the keys of
    :data:`CONDITION_KEYS`; a null is the key left out (its default, or "required")."""
    from grassd.sim.lighting import MAX_LUX

    if not isinstance(data, dict):
        raise StudioInputError("send a JSON object")
    unknown = [_shown(k) for k in data if k not in CONDITION_KEYS]
    if unknown:
        raise StudioInputError(f"unknown key{'s' if len(unknown) > 1 else ''} "
                               f"{', '.join(unknown[:5])}{', ...' if len(unknown) > 5 else ''} "
                               f"in the condition: it takes " + ", ".join(CONDITION_KEYS))
    data = _given(data)
    light = data.get("light", default_light)
    if not isinstance(light, str) or light not in lights:
        raise StudioInputError(f"light {_shown(light)} is not one of the studio's: "
                               + ", ".join(sorted(lights)))
    lux = _number(data, "ambient_lux", lo=1e-3, hi=MAX_LUX, unit="lx")
    splay = (None if data.get("splay_deg") is None
             else _number(data, "splay_deg", lo=0.0, hi=MAX_SPLAY_DEG, unit="deg"))
    lengths = (parse_lengths(data["lengths_mm"], green_max_mm) if "lengths_mm" in data
               else default_lengths(green_max_mm))
    tables = data.get("tables", "live")
    if not isinstance(tables, str) or tables not in ("live", "active"):
        raise StudioInputError(f"tables must be \"live\" or \"active\", got {_shown(tables)}")
    image = data.get("image")
    if image is not None and not isinstance(image, str):
        raise StudioInputError(f"image must be the id an upload returned, got {_shown(image)}")
    pixel = data.get("pixel")
    if pixel is not None and (not isinstance(pixel, str) or pixel not in ("config", "fit")):
        raise StudioInputError(f"pixel must be \"config\" or \"fit\", got {_shown(pixel)}")
    target = _number(data, "target_stderr", TARGET_STDERR, lo=STDERR_BOUNDS[0],
                     hi=STDERR_BOUNDS[1], unit="dE00")
    return Condition(
        light=light, ambient_lux=lux, sun=parse_sun(data, timezone),
        viewpoint=parse_viewpoint(data.get("viewpoint")), splay_deg=splay,
        length_mm=_number(data, "length_mm", green_max_mm / 2, lo=0.0, hi=green_max_mm,
                          unit="mm"),
        lengths_mm=lengths, tables=tables, image=image, target_stderr=target, pixel=pixel)
