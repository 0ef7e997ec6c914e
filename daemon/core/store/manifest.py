"""A light bundle's manifest: read from its file, validated, and checked to describe light
that can have been.

A bundle (:mod:`grassd.daemon.core.store.ingest`) holds ``manifest.toml`` or ``manifest.json`` (a
flat bundle ``<name>.manifest.toml``) and the files it names. Manifest keys::

    timestamp = 2026-06-21T12:00:00+02:00   # TOML datetime or ISO 8601 string; naive = site time
    hdri = "sky.exr"                         # equirectangular HDRI, .exr or .hdr
    ambient_lux = 12000.0                    # optional when a Modbus lux sensor is configured
    sun_lux = 40000.0                        # optional: (lux with sun) - (lux without)
    sun_azimuth_deg = 180.0                  # optional, with sun_elevation_deg
    sun_elevation_deg = 35.0
    checker_raw = "checker.dng"              # optional colour-checker RAW
    checker_corners = [[x, y], x4]           # chart corners in the RAW (pixels), with checker_raw
    checker_chart = "spydercheckr-24"        # optional: reference chart (or colorchecker-classic)
    [capture]                                # optional: how a capture station made it
    sun_clipped = true                       #   (camera, exposures, merge; archived as is);
                                             #   sun_clipped: restore the sun from lux

The light and checker keys, their types and ranges are those of every light document
(:mod:`grassd.daemon.core.config.manifest_fields`, shared with a capture directory's capture.toml).

A manifest must also describe light that can have been: :func:`check_light` refuses light stamped
in the future (beyond ``[light] future_tolerance_s`` of the daemon's own clock: a camera whose
clock was never set would otherwise make every later bundle look older, so it could pin the
active table) and a sun reading that contradicts itself or the site and time (a sun below the
horizon that gives lux, more lux than sunlight has, a direction far from the sun's position).
Such a bundle is rejected at once, with the reason.
"""

from __future__ import annotations

import json
import os
import tomllib
from dataclasses import dataclass
from datetime import UTC, datetime, tzinfo
from pathlib import Path
from typing import Any

from grassd.daemon.core.config import manifest_fields, schema
from grassd.daemon.core.config.limits import DEFAULT_LIMITS, FUTURE_TOLERANCE_S
from grassd.daemon.core.errors import ManifestError
from grassd.daemon.core.store.untrusted import UntrustedFileError, read_regular
from grassd.daemon.core.timestamps import utc_iso
from grassd.sim.errors import LightingError
from grassd.sim.light_input import LightInput
from grassd.sim.sun import check_sun_reading

#: A bundle directory's manifest file names
MANIFEST_NAMES = ("manifest.toml", "manifest.json")
#: How deeply a manifest's arrays and tables may nest (a real one: 3, checker_corners)
MAX_MANIFEST_DEPTH = 8


@dataclass(frozen=True)
class CheckerPhoto:
    """A bundle's colour-checker RAW: file, the chart's four corners in it (pixels, top-left
    first, clockwise) and the reference chart's name (:func:`grassd.calib.charts.get_chart`)."""

    raw: Path
    corners: tuple[tuple[float, float], ...]
    chart: str = manifest_fields.DEFAULT_CHART


@dataclass(frozen=True)
class Manifest:
    """A validated bundle manifest; paths are absolute (inside the bundle's directory).

    ``light``: the measured light (``ambient_lux`` None when the manifest leaves it to the lux
    sensor; ``timestamp`` always set, timezone-aware; ``sun_from_hdri`` set by the ``[capture]``
    table's ``sun_clipped = true``, written by ``grassd capture``, the rest of which is
    metadata); ``checker``: the colour-checker photo, if the bundle has one.
    """

    light: LightInput
    checker: CheckerPhoto | None = None

    @property
    def timestamp(self) -> datetime:
        """When the light was measured (timezone-aware; a manifest always has one)."""
        return self.light.timestamp  # type: ignore[return-value]  # parse_manifest sets it

    def files(self) -> list[Path]:
        """The data files the manifest names."""
        return [self.light.hdri] + ([] if self.checker is None else [self.checker.raw])


def read_manifest_data(path: Path,
                       max_bytes: int = DEFAULT_LIMITS.manifest_bytes) -> dict[str, Any]:
    """Parse a TOML or JSON manifest file into a dict (ManifestError when malformed).

    The file must be a regular file of at most ``max_bytes`` bytes (never a link, FIFO or
    device: :mod:`grassd.daemon.core.store.untrusted`); a parse error of any kind (bad syntax,
    encoding, nesting deeper than MAX_MANIFEST_DEPTH or than the parser's recursion limit)
    is a ManifestError naming the file."""
    return read_manifest_text(path, max_bytes)[1]


def read_manifest_text(path: Path, max_bytes: int = DEFAULT_LIMITS.manifest_bytes
                       ) -> tuple[str, dict[str, Any]]:
    """(the text, the data) of a TOML or JSON manifest file, read and checked as
    :func:`read_manifest_data` does (the text: for locating a key's line)."""
    try:
        raw = read_regular(path, max_bytes)
    except UntrustedFileError as exc:
        raise ManifestError(f"manifest {exc}") from None
    except OSError as exc:
        raise ManifestError(f"cannot read manifest {path.name}: {exc.strerror}") from None
    kind = "JSON" if path.name.endswith(".json") else "TOML"
    try:
        text = raw.decode("utf-8")
        if path.name.endswith(".json"):
            data = json.loads(text)
        else:
            data = tomllib.loads(text)
    except RecursionError:
        data = None  # nested past the parser's own limit: reported as too deep below
    except (ValueError, TypeError) as exc:  # UnicodeDecodeError, JSON/TOMLDecodeError
        # and whatever else a parser raises on hostile text
        raise ManifestError(f"manifest {path.name} is not valid {kind}: {exc}") from None
    if data is None or _depth(data) > MAX_MANIFEST_DEPTH:
        raise ManifestError(f"manifest {path.name} nests arrays or tables more than "
                            f"{MAX_MANIFEST_DEPTH} deep: not a manifest grassd reads")
    if not isinstance(data, dict):
        raise ManifestError(f"manifest {path.name} must hold a table/object at top level")
    return text, data


def load_bundle_manifest(directory: Path, tz: tzinfo = UTC,
                         max_bytes: int = DEFAULT_LIMITS.manifest_bytes) -> Manifest | None:
    """The manifest of the bundle directory ``directory`` (its ``manifest.toml`` or
    ``manifest.json``, the first there), read and validated, naive times in ``tz``; None when
    it has neither. ManifestError when it cannot be read or is invalid."""
    path = next((directory / m for m in MANIFEST_NAMES if os.path.lexists(directory / m)), None)
    if path is None:
        return None
    return parse_manifest(read_manifest_data(path, max_bytes), directory, tz)


def _depth(v: Any) -> int:
    """How deeply lists and dicts nest in ``v`` (a scalar: 0); stops counting past
    MAX_MANIFEST_DEPTH + 1, so it never recurses deeply."""
    depth, level = 0, [v]
    while level and depth <= MAX_MANIFEST_DEPTH:
        nxt: list[Any] = []
        for x in level:
            if isinstance(x, dict):
                nxt.extend(x.values())
            elif isinstance(x, list):
                nxt.extend(x)
        if not nxt and not any(isinstance(x, dict | list) for x in level):
            break
        depth += 1
        level = nxt
    return depth


def parse_manifest(data: dict[str, Any], base: Path, tz: tzinfo = UTC) -> Manifest:
    """Validate manifest ``data``; file names resolve inside ``base``; naive times are in ``tz``.

    Checks names and ranges only, not that the files exist (see :func:`missing_files`).
    Raises :class:`ManifestError` naming the key (:mod:`grassd.daemon.core.config.schema`).
    """
    ctx = schema.Context("", None, base, error=ManifestError)
    F = schema.Field
    m = schema.table(ctx, (), data, {
        "timestamp": F(str | datetime, hint="a date-time, ISO 8601, e.g. "
                       "2026-06-21T12:00:00+02:00"),
        **manifest_fields.light_fields(plain_names=True, ambient_required=False),
        "capture": F(dict, None, hint="a table (written by grassd capture)"),
    })
    ts = m["timestamp"]
    if isinstance(ts, str):
        try:
            ts = datetime.fromisoformat(ts.replace("Z", "+00:00"))
        except ValueError:
            raise ctx.error(("timestamp",), f"{ts!r} is not ISO 8601 (e.g. "
                            "2026-06-21T12:00:00+02:00)") from None
    if ts.tzinfo is None:
        ts = ts.replace(tzinfo=tz)
    manifest_fields.check_together(ctx, m)
    raw, corners = m["checker_raw"], m["checker_corners"]
    capture = m["capture"]
    light = LightInput(hdri=base / m["hdri"], ambient_lux=m["ambient_lux"], sun_lux=m["sun_lux"],
                       sun_azimuth_deg=m["sun_azimuth_deg"],
                       sun_elevation_deg=m["sun_elevation_deg"],
                       sun_from_hdri=bool(capture and capture.get("sun_clipped") is True),
                       timestamp=ts)
    checker = None if raw is None else CheckerPhoto(
        base / raw, manifest_fields.as_quad(corners), m["checker_chart"])
    return Manifest(light, checker)


def check_light(m: Manifest, *, now: float, future_tolerance_s: float = FUTURE_TOLERANCE_S,
                site: tuple[float, float] | None = None) -> None:
    """Refuse a manifest whose light cannot have been captured (ManifestError, with the fix).

    ``now``: the daemon's clock (epoch s). Light stamped more than ``future_tolerance_s``
    seconds after ``now`` is refused: a newer timestamp outranks every later bundle (older light
    is superseded), so one camera clock set years ahead would pin the active table. Light from
    long ago is fine: such a bundle is simply superseded. ``site``: (latitude, longitude) in
    degrees, east +; with it the sun reading is checked against the sun's position at the
    manifest's time (:func:`grassd.sim.sun.check_sun_reading`), without it only against itself.
    """
    ahead = m.timestamp.timestamp() - now
    if ahead > future_tolerance_s:
        clock = utc_iso(now)
        raise ManifestError(
            f"light from the future: timestamp {m.timestamp.isoformat()} is "
            f"{_duration(ahead)} ahead of the daemon's clock ({clock}); tolerance "
            f"{future_tolerance_s:g} s ([light] future_tolerance_s). Set the capture device's "
            f"clock (and time zone) right, then send the bundle again")
    lat, lon = site if site is not None else (None, None)
    try:
        check_sun_reading(m.light.sun_lux, m.light.sun_azimuth_deg, m.light.sun_elevation_deg,
                          latitude_deg=lat, longitude_deg=lon, when=m.timestamp)
    except LightingError as exc:
        raise ManifestError(f"impossible sun: {exc}") from None


def _duration(seconds: float) -> str:
    """``seconds`` in the largest fitting unit, e.g. '26.5 h', '73.0 days'."""
    for unit, size in (("years", 365.25 * 86400), ("days", 86400.0), ("h", 3600.0),
                       ("min", 60.0)):
        if seconds >= 2 * size:
            return f"{seconds / size:.1f} {unit}"
    return f"{seconds:.0f} s"
