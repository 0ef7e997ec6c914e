"""The light and colour-checker keys that every light document shares, and their checks.

Two documents describe a light measurement: a light bundle's ``manifest.toml``
(:mod:`grassd.daemon.core.store.manifest`) and a capture directory's ``capture.toml``
(:mod:`grassd.daemon.offline.validate`). They use the same names, with the same types and
ranges, defined here once::

    hdri = "sky.exr"                  # equirectangular panorama, .exr or .hdr
    ambient_lux = 12000.0             # horizontal illuminance, sun shaded [lx], 0 < lux <= MAX_LUX
    sun_lux = 40000.0                 # (lux with sun) - (lux without) [lx], 0 <= lux <= MAX_LUX
    sun_azimuth_deg = 180.0           # compass azimuth of the sun [deg], 0..360, with
    sun_elevation_deg = 35.0          #   its elevation [deg], -90..90 (both or neither)
    checker_raw = "checker.dng"       # RAW photo of the colour checker, with
    checker_corners = [[x, y], x4]    #   the chart's corners in it (pixels, top-left first,
                                      #   clockwise)
    checker_chart = "spydercheckr-24" # reference chart (grassd.calib.charts.get_chart)

What differs is how a file is named: a bundle comes from an untrusted inbox, so its files are
plain names inside the bundle (``plain_names=True``); a capture directory is the user's own, so
its files are paths, relative to the directory or absolute.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from pathlib import Path

from grassd.daemon.core.config import schema
from grassd.sim.lighting import MAX_LUX

#: The panorama formats the renderer reads (OpenEXR, Radiance).
HDRI_SUFFIXES = (".exr", ".hdr")
#: The reference chart when a document names none (:func:`grassd.calib.charts.get_chart`).
DEFAULT_CHART = "spydercheckr-24"
#: The shared keys, in the order a writer writes them.
LIGHT_KEYS = ("hdri", "ambient_lux", "sun_lux", "sun_azimuth_deg", "sun_elevation_deg")
CHECKER_KEYS = ("checker_raw", "checker_corners", "checker_chart")


def plain_name(v: schema.TomlValue) -> bool:
    """True when ``v`` is a plain file name (no directory part, not ``.`` or ``..``)."""
    return isinstance(v, str) and bool(v) and "/" not in v and "\\" not in v \
        and v not in (".", "..")


def lux(lo_exclusive: bool) -> Callable[[float], str | None]:
    """Check: a lux reading [lx] > 0 (``lo_exclusive``) or >= 0, and <= MAX_LUX."""
    def check(v: float) -> str | None:
        if (v <= 0 if lo_exclusive else v < 0) or v > MAX_LUX:
            return (f"{v:g} lux is impossible: it must be {'>' if lo_exclusive else '>='} 0 and "
                    f"<= {MAX_LUX:g} lux")
        return None

    return check


def file_name(plain_names: bool) -> Callable[[str], str | None]:
    """Check: a data file's name; a plain name inside the bundle (``plain_names``), else any
    non-empty path."""
    def check(v: str) -> str | None:
        if plain_names and not plain_name(v):
            return f"must be a plain file name inside the bundle, got {v!r}"
        return schema.non_empty(v)

    return check


def chart_name(plain_names: bool) -> Callable[[str], str | None]:
    """Check: the reference chart; a bundle's (``plain_names``) one of the built-in charts
    (:data:`grassd.calib.charts.CHARTS`: a bundle never makes the daemon read a file it does
    not hold), else a built-in name or a CSV file's path (resolved by the reader)."""
    def check(v: str) -> str | None:
        from grassd.calib.charts import CHARTS, chart_key

        if plain_names and chart_key(v) not in CHARTS:
            return (f"must be a built-in chart ({', '.join(CHARTS)}), got {v!r}; a chart "
                    "CSV is for a capture directory (grassd validate)")
        return schema.non_empty(v)

    return check


def hdri_name(plain_names: bool) -> Callable[[str], str | None]:
    """Check: the panorama's name (see :func:`file_name`), ending in .exr or .hdr."""
    name_check = file_name(plain_names)

    def check(v: str) -> str | None:
        wrong = name_check(v)
        if wrong:
            return wrong
        if Path(v).suffix.lower() not in HDRI_SUFFIXES:
            return f"{v!r} must be an OpenEXR (.exr) or Radiance (.hdr) file"
        return None

    return check


def quad(v: list[schema.TomlValue]) -> str | None:
    """Check: four [x, y] image positions (pixels, finite), in order around the area."""
    ok = len(v) == 4 and all(isinstance(c, list) and schema.numbers(2)(c) is None for c in v)
    return None if ok else ("must be four [x, y] image positions (pixels), in order around the "
                            f"area, top-left first, clockwise; got {v!r}")


def as_quad(v: list) -> tuple[tuple[float, float], ...]:
    """Corners already checked by :func:`quad` as a tuple of (x, y) pixels."""
    return tuple((float(x), float(y)) for x, y in v)


def light_fields(*, plain_names: bool, ambient_required: bool) -> dict[str, schema.Field]:
    """The schema of the shared keys (module docstring): ``hdri`` required, ``ambient_lux``
    required when ``ambient_required`` (else None: a lux sensor reads it), the rest optional
    (None; ``checker_chart``: :data:`DEFAULT_CHART`)."""
    F = schema.Field
    return {
        "hdri": F(str, check=hdri_name(plain_names),
                  hint="the name of the .exr or .hdr panorama"),
        "ambient_lux": F(float, schema.MISSING if ambient_required else None,
                         lux(lo_exclusive=True)),
        "sun_lux": F(float, None, lux(lo_exclusive=False)),
        "sun_azimuth_deg": F(float, None, schema.between(0.0, 360.0, " degrees")),
        "sun_elevation_deg": F(float, None, schema.between(-90.0, 90.0, " degrees")),
        "checker_raw": F(str, None, file_name(plain_names)),
        "checker_corners": F(list, None, quad),
        "checker_chart": F(str, DEFAULT_CHART, chart_name(plain_names)),
    }


def check_together(ctx: schema.Context, values: Mapping[str, schema.TomlValue],
                   path: Callable[[str], tuple] = lambda key: (key,)) -> None:
    """The rules between the shared keys of a validated table ``values``: the sun's azimuth and
    elevation both or neither; ``checker_raw`` and ``checker_corners`` both or neither.
    ``path``: where a key was written (for the error's name and line); raises ``ctx.error``."""
    if (values["sun_azimuth_deg"] is None) != (values["sun_elevation_deg"] is None):
        raise ctx.error(path("sun_azimuth_deg")[:-1],
                        "give both sun_azimuth_deg and sun_elevation_deg, or neither")
    raw, corners = values["checker_raw"], values["checker_corners"]
    if corners is not None and raw is None:
        raise ctx.error(path("checker_corners"), "given without checker_raw")
    if raw is not None and corners is None:
        raise ctx.error(path("checker_raw"), "needs checker_corners: the four chart corners in "
                        "the RAW image (pixels, top-left first, clockwise)")
