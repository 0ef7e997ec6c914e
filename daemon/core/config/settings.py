"""The daemon's configuration: TOML file -> validated, frozen dataclasses.

The file is ``/etc/grassd/grassd.toml`` by default (:data:`DEFAULT_CONFIG_PATH`). The embedded
default, ``grassd/daemon/core/config/default.toml``, documents every key the schema accepts,
with its default and bounds (``tests/daemon/config/test_default_documents_every_key.py`` holds
it to that), so the tables are not listed again here: the core's sections are the dataclasses
below; the features' are parsed by their own modules (``[capture]``:
:mod:`grassd.daemon.camera.config`; ``[measure]``, ``[compute]``, ``[content]``: the
``config`` module of ``grassd.daemon.measure``, ``.compute``, ``.content``).

Relative paths are resolved against the directory of the config file, except ``light.inbox``
which, when relative, lies inside ``state_dir``.

Validation is strict: an unknown key, a missing required key, a wrong type (``true`` where a
number belongs; ``1`` is accepted for a float, never for a bool) or an out-of-range value raises
:class:`~grassd.daemon.core.errors.ConfigError` naming the dotted key and the file line (the schema
machinery of :mod:`grassd.daemon.core.config.schema`). Each default is written once, on its
dataclass.
"""

from __future__ import annotations

import dataclasses
import os
import re
import shlex
import tomllib
import types
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeAlias

from grassd.daemon.compute.config import (  # noqa: F401 (scheduler_address_problem)
    ComputeConfig,
    parse_compute,
    scheduler_address_problem,
)
from grassd.daemon.core.config.limits import DEFAULT_LIMITS, FUTURE_TOLERANCE_S, BundleLimits
from grassd.daemon.core.config.schema import Context as _Ctx
from grassd.daemon.core.config.schema import Field as _F
from grassd.daemon.core.config.schema import Section as _Section
from grassd.daemon.core.config.schema import TomlTable, TomlValue
from grassd.daemon.core.config.schema import between as _between
from grassd.daemon.core.config.schema import check_type as _check_type
from grassd.daemon.core.config.schema import non_empty as _non_empty
from grassd.daemon.core.config.schema import non_negative as _non_negative
from grassd.daemon.core.config.schema import numbers as _numbers
from grassd.daemon.core.config.schema import one_of as _one_of
from grassd.daemon.core.config.schema import positive as _positive
from grassd.daemon.core.config.schema import schema as _schema
from grassd.daemon.core.errors import ConfigError
from grassd.firmware_proto.framing import MAX_ADDRESS, MIN_ADDRESS
from grassd.sim.errors import SimError
from grassd.sim.kernel_cache import default_cache_dir
from grassd.sim.scene import MAX_REPLICATES, PixelSpec

if TYPE_CHECKING:
    from grassd.daemon.camera.config import CaptureConfig
    from grassd.daemon.content.config import ContentConfig
    from grassd.daemon.measure.config import MeasureConfig

#: Where the packaged daemon looks when no ``--config`` is given.
DEFAULT_CONFIG_PATH = Path("/etc/grassd/grassd.toml")
#: The help of every command's ``--config`` option.
CONFIG_OPTION_HELP = (f"configuration file (default {DEFAULT_CONFIG_PATH}; "
                      "the embedded default when that is absent)")
#: The service's RuntimeDirectory (exists while it runs); holds the control socket.
SYSTEM_RUNTIME_DIR = Path("/run/grassd")

#: A ``[display.pixel]`` value: a number (mm, a count) or an sRGB triple.
PixelValue: TypeAlias = float | tuple[float, ...]

MODBUS_MODES = ("rtu", "tcp")
WORD_ORDERS = ("big", "little")
VALUE_TYPES = ("uint", "int", "float")
#: ``[simulation] transport``: spectral (the Rec.709 trace plus spectra's difference) or rgb
TRANSPORTS: tuple[str, ...] = ("spectral", "rgb")


# --------------------------------------------------------------------------- dataclasses


@dataclass(frozen=True)
class SiteConfig:
    """Where the display stands: latitude/longitude in degrees (north/east positive)."""

    latitude: float
    longitude: float
    timezone: str = "UTC"


@dataclass(frozen=True)
class DisplayConfig:
    """Display geometry: ``rows`` x ``cols`` grass pixels at ``pitch_mm`` centre spacing.

    ``pixel`` holds the pixel-spec fields (mm / counts) as a read-only mapping; pass it to
    ``grassd.sim.scene.PixelSpec(**pixel)``.
    """

    rows: int
    cols: int
    pitch_mm: float = 33.5
    pixel: Mapping[str, PixelValue] = field(kw_only=True)

    @property
    def pixel_count(self) -> int:
        """Number of grass pixels (rows x cols)."""
        return self.rows * self.cols

    @property
    def green_max_mm(self) -> float:
        """The longest green length a pixel shows [mm]: ``pixel["green_max_mm"]``, else
        PixelSpec's default; no table entry may exceed it."""
        v = self.pixel.get("green_max_mm", PixelSpec.green_max_mm)
        return float(v) if isinstance(v, int | float) else PixelSpec.green_max_mm


@dataclass(frozen=True)
class ControllerConfig:
    """One controller: serial ``port`` (use /dev/serial/by-id/...), ``baud``, bus ``address``.

    ``pixels`` is a tuple of inclusive (first, last) pixel-index ranges that it drives.
    """

    port: str
    baud: int = 115200
    address: int = 1
    pixels: tuple[tuple[int, int], ...] = field(kw_only=True)

    @property
    def name(self) -> str:
        """Stable identifier ``port#address`` used in history and status."""
        return f"{self.port}#{self.address}"


@dataclass(frozen=True)
class ViewpointConfig:
    """A viewer: eye height ``h_cm`` (cm), distance ``d_m`` (m), angle ``theta_deg`` (deg)."""

    h_cm: float
    d_m: float
    theta_deg: float = 0.0
    weight: float = 1.0


@dataclass(frozen=True)
class ModbusConfig:
    """Register map of a Modbus lux sensor; lux = scale x decoded register value + offset."""

    mode: str = "tcp"
    host: str = "127.0.0.1"
    port: int = 502
    serial_port: str = ""
    baud: int = 9600
    unit: int = 1
    function_code: int = 4
    register: int = 0
    words: int = 1
    word_order: str = "big"
    value_type: str = "uint"
    scale: float = 1.0
    offset: float = 0.0
    timeout_s: float = 1.0
    retries: int = 3


@dataclass(frozen=True)
class LightConfig:
    """Light inputs: bundle ``inbox`` directory and where lux comes from.

    ``lux == "manifest"``: the manifest must carry ambient lux. ``lux == "modbus"``: manifest lux
    wins when present, otherwise the sensor described by ``modbus`` is read. A bundle is picked
    up once its files have kept their sizes for ``settle_s`` seconds; a manifest whose files are
    still missing after ``incomplete_timeout_s`` seconds is rejected. A bundle that needs the
    sensor while it is unreachable or silent waits (retried with backoff) up to ``lux_wait_s``
    seconds before it is rejected; a reading that is not a usable illuminance rejects it at once.
    A bundle whose light is stamped more than ``future_tolerance_s`` seconds after the daemon's
    clock is rejected (:func:`grassd.daemon.core.store.manifest.check_light`).
    ``hdri_flip``/``hdri_rotation_deg`` bring the site camera's panoramas into the renderer's
    convention (:mod:`grassd.sim.lighting`: u = atan2(y, x) / 2 pi, +y north): most 360-degree
    cameras store the mirror image, so a real site wants ``hdri_flip = true``, and the rotation
    (degrees, counter-clockwise seen from above) puts north where the camera did not; without
    them a sun placed from the site's latitude, longitude and time misses the sun in the map.
    ``limits`` (``[light.limits]``): caps on a bundle's manifest, files and entries
    (:class:`~grassd.daemon.core.config.limits.BundleLimits`); a bundle over one is rejected.
    """

    inbox: Path
    lux: str = "manifest"
    modbus: ModbusConfig | None = None
    settle_s: float = 2.0
    incomplete_timeout_s: float = 600.0
    lux_wait_s: float = 900.0
    future_tolerance_s: float = FUTURE_TOLERANCE_S
    hdri_flip: bool = False
    hdri_rotation_deg: float = 0.0
    limits: BundleLimits = DEFAULT_LIMITS


@dataclass(frozen=True)
class ScheduleConfig:
    """``interval_s``: recalibrate at least this often (0 = only on new bundles / requests)."""

    interval_s: float = 3600.0
    on_new_bundle: bool = True


@dataclass(frozen=True)
class RetentionConfig:
    """How much the state directory keeps (pruned after every run,
    :mod:`grassd.daemon.core.runtime.retention`).

    ``keep_days``: archived and rejected bundles older than this (days) are deleted, except the
    latest archived bundle (the light of scheduled runs); ``keep_reports``: JSON + PNG reports
    of at most this many runs are kept (the active table's report always); ``keep_runs``:
    history rows of at most this many runs are kept (the active table's run always).
    """

    keep_days: float = 30.0
    keep_reports: int = 500
    keep_runs: int = 5000


@dataclass(frozen=True)
class SimulationConfig:
    """Monte Carlo ``samples`` per pixel measurement, RNG ``seed``, green lengths in mm, and
    the random tuft ``layouts`` a global table's characteristic averages (replicate j traces
    layout j mod layouts, so at most ``[calibration] replicates`` of them are traced;
    :func:`grassd.daemon.core.calibration.simulation.simulate_curve` gives the measurements: the
    mean of 8 is 2-3x closer to the mean of all layouts than one: docs/calibration.md). The
    layouts' spread enters each length's OGCD error but hardly its steps (a layout moves the
    whole curve), so the shape check reads the steps' own errors
    (:attr:`grassd.daemon.core.calibration.simulation.SimulatedCurve.step_stderr`).

    ``transport``: how the characteristic carries light (:data:`TRANSPORTS`): "spectral" adds
    to every replicate the difference spectral transport makes, recorded on 1 in
    ``spectral_share`` of its paths (:mod:`grassd.daemon.core.calibration.transport`); "rgb"
    is the renderer's Rec.709 channels alone."""

    samples: int = 4096
    seed: int = 0
    layouts: int = 8
    transport: str = "spectral"
    spectral_share: int = 16
    lengths_mm: tuple[float, ...] = field(kw_only=True)


@dataclass(frozen=True)
class CalibrationConfig:
    """Checks and closed loop of a calibration run (dE00 = CIEDE2000 units).

    ``max_jump_mm``: largest change of any table entry from the last table (mm) accepted
    without ``--force``; ``target_de00``/``max_rounds``/``check_levels``: the closed loop stops
    when the largest |OGCD - target| over ``check_levels`` levels is <= ``target_de00`` or after
    ``max_rounds`` rounds; ``r2_goal``: reported goal for R^2 of OGCD vs level;
    ``max_flat_fraction``: refuse a characteristic whose share of flat steps exceeds this;
    ``replicates``: independent Monte Carlo replicates per render (their spread = error);
    ``ccm``: the colour correction fitted to a bundle's checker RAW, "auto" (the form of
    lowest leave-one-out CIEDE2000, :func:`grassd.calib.ccm.select_ccm`) or one form of
    :data:`CCM_CHOICES`.
    """

    max_jump_mm: float = 3.0
    target_de00: float = 0.5
    max_rounds: int = 3
    check_levels: int = 17
    r2_goal: float = 0.999
    max_flat_fraction: float = 0.6
    replicates: int = 8
    ccm: str = "auto"


#: ``[calibration] ccm``: "auto" and the forms of :data:`grassd.calib.ccm.CCM_FORMS` (named
#: here, since the configuration loads without numpy; a test keeps the two equal).
CCM_CHOICES: tuple[str, ...] = ("auto", "3x3", "root-polynomial-2", "root-polynomial-3")


@dataclass(frozen=True)
class TablesConfig:
    """Whole-display tables (:mod:`grassd.daemon.core.calibration.display_model`).

    ``granularity``: "global" (one table), "controller" (one per controller, its pixels' mean
    characteristic) or "pixel"; ``eye``: "world" (a viewpoint is one spot relative to the
    display centre, every pixel seen from its own direction) or "pixel" (each pixel seen from
    the same relative viewpoint); pixels whose view directions differ by less than
    ``group_tolerance_deg`` (deg) and distances by less than ``distance_tolerance`` (relative)
    share one simulation; ``check_groups`` groups are re-simulated to report the grouping error.
    ``layout``: the simulated tuft layout, "shared" (one random layout copied to every pixel),
    "per_pixel" (each pixel draws its own) or "auto" (shared for "pixel" tables, per pixel
    otherwise; see :func:`grassd.daemon.core.calibration.display_model.display_spec_for_config`).
    The daemon pushes them (:mod:`grassd.daemon.core.calibration.units`): "controller" gives each
    controller one (256,) table, "pixel" an (n_pixels, 256) table for the pixels it drives;
    "global" without ``[audience]`` gives one table, from the centre pixel.
    """

    granularity: str = "global"
    eye: str = "world"
    group_tolerance_deg: float = 2.0
    distance_tolerance: float = 0.1
    check_groups: int = 4
    layout: str = "auto"


@dataclass(frozen=True)
class AudienceConfig:
    """An audience region (:mod:`grassd.daemon.core.calibration.audience`): ground ``polygon`` of
    (x, y) metres (display centre at the origin, +x east, +y north), eye heights ``h_cm`` = (low,
    high) cm, sampled with about ``ground_samples`` points x ``height_samples`` heights; the table
    minimises the ``objective`` ("mean" or "worst") deviation from linear OGCD."""

    polygon: tuple[tuple[float, float], ...]
    h_cm: tuple[float, float]
    ground_samples: int = 16
    height_samples: int = 2
    objective: str = "mean"


@dataclass(frozen=True)
class MetricsConfig:
    """Prometheus metrics (:mod:`grassd.daemon.core.monitoring.metrics`): ``textfile`` is the file
    written for node_exporter's textfile collector after every run and reconcile; None: the
    default (:func:`grassd.daemon.core.monitoring.metrics.textfile_path`: Debian's node-exporter
    directory when it exists, else ``state_dir/metrics/grassd.prom``)."""

    textfile: Path | None = None


@dataclass(frozen=True)
class AlertsConfig:
    """Alerts without Prometheus (:mod:`grassd.daemon.core.monitoring.alerts`): ``command`` (split
    like a shell line, run without a shell; None: no alerts) runs when health changes between
    ok, degraded and failed, with a JSON description of the change on its standard input; at
    most one run per ``min_interval_s`` seconds (changes meanwhile are summed up in the next);
    a run still going after ``timeout_s`` seconds is killed."""

    command: str | None = None
    min_interval_s: float = 300.0
    timeout_s: float = 60.0


@dataclass(frozen=True)
class Config:
    """The whole validated configuration. ``source`` is the file it came from."""

    site: SiteConfig
    display: DisplayConfig
    controllers: tuple[ControllerConfig, ...]
    viewpoints: tuple[ViewpointConfig, ...]
    light: LightConfig
    schedule: ScheduleConfig
    simulation: SimulationConfig
    calibration: CalibrationConfig
    state_dir: Path
    cache_dir: Path
    control_socket: Path
    source: str
    tables: TablesConfig = TablesConfig()
    audience: AudienceConfig | None = None
    retention: RetentionConfig = RetentionConfig()
    metrics: MetricsConfig = MetricsConfig()
    alerts: AlertsConfig = AlertsConfig()
    compute: ComputeConfig = ComputeConfig()
    #: the capture station (:mod:`grassd.daemon.camera.config`), None without [capture]
    capture: CaptureConfig | None = None
    #: the display's measuring camera (:mod:`grassd.daemon.measure.config`), None without
    measure: MeasureConfig | None = None
    #: what the display shows (:mod:`grassd.daemon.content.config`), None without [content]
    content: ContentConfig | None = None

    @property
    def serial_ports(self) -> list[str]:
        """The serial ports the daemon owns: the controllers' buses and, in RTU mode, the lux
        sensor's RS-485 port (sorted, each once)."""
        ports = {c.port for c in self.controllers}
        modbus = self.light.modbus
        if modbus is not None and modbus.mode == "rtu":
            ports.add(modbus.serial_port)
        return sorted(ports)

    def replace(self, **changes: Any) -> Config:
        """A copy with some fields replaced (dataclasses.replace)."""
        return dataclasses.replace(self, **changes)

    def with_state_dir(self, state_dir: Path) -> Config:
        """A copy whose state directory is ``state_dir``; paths that lay inside the old state
        directory (inbox, cache, control socket) move along with it."""
        new = Path(state_dir)

        def move(p: Path) -> Path:
            try:
                return new / p.relative_to(self.state_dir)
            except ValueError:
                return p

        light = dataclasses.replace(self.light, inbox=move(self.light.inbox))
        return dataclasses.replace(self, state_dir=new, light=light,
                                   cache_dir=move(self.cache_dir),
                                   control_socket=move(self.control_socket))


# --------------------------------------------------------------------------- checks


def _timezone(v: str) -> str | None:
    from zoneinfo import ZoneInfo, ZoneInfoNotFoundError  # 30 ms: only a [site] timezone

    try:
        ZoneInfo(v)
    except (ZoneInfoNotFoundError, ValueError):
        return f"unknown time zone {v!r} (use an IANA name such as 'Europe/Berlin' or 'UTC')"
    return None


# --------------------------------------------------------------------------- sections


def _pixel_fields() -> dict[str, PixelValue]:
    """Pixel-spec field defaults: those of :class:`grassd.sim.scene.PixelSpec`."""
    spec = PixelSpec()
    out: dict[str, PixelValue] = {}
    for f in dataclasses.fields(spec):
        v = getattr(spec, f.name)
        if isinstance(v, int | float) and not isinstance(v, bool) or (
                isinstance(v, tuple) and all(isinstance(x, int | float) for x in v)):
            out[f.name] = v
    return out


def _check_pixel_spec(sec: _Section, pixel: dict[str, PixelValue]) -> None:
    """Let grassd.sim.scene.PixelSpec validate the fields together."""
    try:
        PixelSpec(**pixel)  # type: ignore[arg-type]  # each value has its default's kind
    except SimError as exc:
        m = re.search(r"PixelSpec\.(\w+)", str(exc))
        key = m.group(1) if m and m.group(1) in pixel else None
        raise sec.error((key,) if key else (), str(exc)) from None
    except TypeError as exc:
        raise sec.error((), str(exc)) from None


_RANGE_RE = re.compile(r"^\s*(\d+)\s*(?:-\s*(\d+)\s*)?$")


def parse_pixel_ranges(spec: str, pixel_count: int) -> tuple[tuple[int, int], ...]:
    """Parse ``"0-63,70"`` into inclusive ranges ``((0, 63), (70, 70))``; ``"all"`` = every pixel.

    Raises ValueError for a malformed or backwards range, a pixel beyond ``pixel_count`` and a
    pixel listed twice (``"0-3,2-5"``).

    >>> parse_pixel_ranges("0-3, 8", 10)
    ((0, 3), (8, 8))
    """
    if spec.strip().lower() == "all":
        return ((0, pixel_count - 1),)
    out = []
    spans = []  # (range, as written), for the overlap check
    for part in spec.split(","):
        m = _RANGE_RE.match(part)
        if not m:
            raise ValueError(f"bad pixel range {part.strip()!r} "
                             "(write e.g. \"0-63,70\" or \"all\")")
        a = int(m.group(1))
        b = int(m.group(2)) if m.group(2) is not None else a
        if b < a:
            raise ValueError(f"pixel range {part.strip()!r} runs backwards")
        if b >= pixel_count:
            raise ValueError(f"pixel {b} does not exist: the display has {pixel_count} pixels")
        out.append((a, b))
        spans.append(((a, b), part.strip()))
    spans.sort()
    for ((_, b1), p1), ((a2, _), p2) in zip(spans, spans[1:], strict=False):
        if a2 <= b1:  # sorted by first pixel: an overlap shows between neighbours
            raise ValueError(f"pixel {a2} is listed twice (in {p1!r} and {p2!r}); list each "
                             "pixel once")
    return tuple(out)


def _resolve(ctx: _Ctx, value: str) -> Path:
    p = Path(os.path.expandvars(os.path.expanduser(value)))
    return p if p.is_absolute() else (ctx.base_dir / p)


def _parse(data: TomlTable, ctx: _Ctx) -> Config:
    """The whole configuration from the TOML ``data``: the top-level keys, then each section
    (one function each, in the order the errors of a file with several mistakes are reported)."""
    top = _Section.read(ctx, (), data, {
        "state_dir": _F(str, None), "cache_dir": _F(str, None), "control_socket": _F(str, None),
        "site": _F(dict), "display": _F(dict), "controllers": _F(list),
        "viewpoints": _F(list), "light": _F(dict), "schedule": _F(dict, {}),
        "simulation": _F(dict, {}), "calibration": _F(dict, {}),
        "tables": _F(dict, {}), "audience": _F(dict, None), "retention": _F(dict, {}),
        "metrics": _F(dict, {}), "alerts": _F(dict, {}),
        "capture": _F(dict, None), "compute": _F(dict, {}), "measure": _F(dict, None),
        "content": _F(dict, None),
    })
    site = _parse_site(top)
    display = _parse_display(top)
    controllers = _parse_controllers(top, display.pixel_count)
    viewpoints = _parse_viewpoints(top)
    state_dir, cache_dir, sock = _parse_paths(top)  # raises nothing
    light = _parse_light(top, state_dir)
    schedule = _parse_schedule(top)
    retention = top.section("retention", _schema(
        RetentionConfig,
        keep_days=_F(float, check=_positive),
        keep_reports=_F(int, check=_between(1, 10**7)),
        keep_runs=_F(int, check=_between(1, 10**9)),
    )).fill(RetentionConfig)
    simulation = _parse_simulation(top, display)
    calibration = top.section("calibration", _schema(
        CalibrationConfig,
        max_jump_mm=_F(float, check=_positive), target_de00=_F(float, check=_positive),
        max_rounds=_F(int, check=_between(1, 10)), check_levels=_F(int, check=_between(3, 256)),
        r2_goal=_F(float, check=_between(0.0, 1.0)),
        max_flat_fraction=_F(float, check=_between(0.0, 1.0)),
        replicates=_F(int, check=_between(2, MAX_REPLICATES)),
        ccm=_F(str, check=_one_of(*CCM_CHOICES)),
    )).fill(CalibrationConfig)
    tables, audience = _parse_tables_audience(top)
    metrics, alerts = _parse_operator(top)
    return Config(site=site, display=display, controllers=controllers,
                  viewpoints=viewpoints, light=light, schedule=schedule,
                  simulation=simulation, calibration=calibration, state_dir=state_dir,
                  cache_dir=cache_dir,
                  control_socket=sock, source=ctx.source, tables=tables, audience=audience,
                  retention=retention, metrics=metrics, alerts=alerts,
                  capture=_capture_section(top),
                  compute=parse_compute(top, _resolve),
                  measure=_measure_section(top, top.get_value("capture") is not None),
                  content=_content_section(top))


def _parse_site(top: _Section) -> SiteConfig:
    """``[site]``: latitude, longitude (degrees) and an IANA time zone."""
    return top.section("site", _schema(
        SiteConfig,
        latitude=_F(float, check=_between(-90, 90, " degrees")),
        longitude=_F(float, check=_between(-180, 180, " degrees")),
        timezone=_F(str, check=_timezone),
    )).fill(SiteConfig)


def _parse_display(top: _Section) -> DisplayConfig:
    """``[display]`` and its ``[display.pixel]`` table (PixelSpec fields, mm and counts)."""
    d = top.section("display", _schema(
        DisplayConfig, rows=_F(int, check=_positive), cols=_F(int, check=_positive),
        pitch_mm=_F(float, check=_positive), pixel=_F(dict, {}),
    ))
    return DisplayConfig(rows=d.get_int("rows"), cols=d.get_int("cols"),
                         pitch_mm=d.get_float("pitch_mm"),
                         pixel=types.MappingProxyType(_parse_pixel(d)))


def _parse_pixel(display: _Section) -> dict[str, PixelValue]:
    """``[display.pixel]``: every PixelSpec field, the table's value else PixelSpec's default
    (arrays as tuples), checked together by PixelSpec itself."""
    defaults = _pixel_fields()
    pschema = {}
    for name, default in defaults.items():
        if isinstance(default, tuple):
            pschema[name] = _F(list, default, _numbers(len(default)))
            continue
        kind = type(default)
        pschema[name] = _F(kind, default, _non_negative)
    sec = display.section("pixel", pschema)
    pixel: dict[str, PixelValue] = {
        name: sec.get_floats(name) if isinstance(default, tuple) else sec.get_float(name)
        for name, default in defaults.items()}
    _check_pixel_spec(sec, pixel)
    return pixel


def _parse_controllers(top: _Section, pixel_count: int) -> tuple[ControllerConfig, ...]:
    """``[[controllers]]``: at least one; no port and address twice, one baud per port, and no
    pixel driven by two controllers (of the display's ``pixel_count``)."""
    controllers: list[ControllerConfig] = []
    if not top.get_list("controllers"):
        raise top.error("controllers", "at least one [[controllers]] entry is required")
    seen_addr: dict[tuple[str, int], int] = {}
    taken: list[tuple[int, int, int]] = []  # (first, last, controller index)
    for i, c in enumerate(top.sections("controllers", _schema(
            ControllerConfig, port=_F(str, check=_non_empty), baud=_F(int, check=_positive),
            address=_F(int, check=_between(MIN_ADDRESS, MAX_ADDRESS)),
            pixels=_F(str, "all"),  # the raw ranges, parsed below
    ))):
        port, baud, address = c.get_str("port"), c.get_int("baud"), c.get_int("address")
        try:
            ranges = parse_pixel_ranges(c.get_str("pixels"), pixel_count)
        except ValueError as exc:
            raise c.error("pixels", str(exc)) from None
        key = (port, address)
        if key in seen_addr:
            raise c.error("address", f"port {port} address {address} is already used by "
                          f"controllers[{seen_addr[key]}]")
        seen_addr[key] = i
        same_bus = next((j for j, o in enumerate(controllers) if o.port == port), None)
        if same_bus is not None and controllers[same_bus].baud != baud:
            raise c.error("baud", f"{baud} differs from the {controllers[same_bus].baud} of "
                          f"controllers[{same_bus}] on the same bus {port} (one port is "
                          "opened once, at one baud)")
        for a, b in ranges:
            for a2, b2, j in taken:
                if a <= b2 and a2 <= b:
                    raise c.error("pixels",
                                  f"pixels {a}-{b} overlap pixels {a2}-{b2} of controllers[{j}]")
        taken.extend((a, b, i) for a, b in ranges)
        controllers.append(ControllerConfig(port=port, baud=baud, address=address,
                                            pixels=ranges))
    return tuple(controllers)


def _parse_viewpoints(top: _Section) -> tuple[ViewpointConfig, ...]:
    """``[[viewpoints]]``: at least one (cm, m, degrees, relative weight)."""
    if not top.get_list("viewpoints"):
        raise top.error("viewpoints", "at least one [[viewpoints]] entry is required")
    return tuple(v.fill(ViewpointConfig) for v in top.sections("viewpoints", _schema(
        ViewpointConfig,
        h_cm=_F(float, check=_between(10, 1000, " cm")),
        d_m=_F(float, check=_between(0.1, 100, " m")),
        theta_deg=_F(float, check=_between(-90, 90, " degrees")),
        weight=_F(float, check=_positive),
    )))


def _parse_paths(top: _Section) -> tuple[Path, Path, Path]:
    """(state directory, cache directory, control socket): the file's keys, else the service's
    environment ($STATE_DIRECTORY, $RUNTIME_DIRECTORY; the cache's:
    :func:`~grassd.sim.kernel_cache.default_cache_dir`), else the defaults the module
    docstring lists."""
    env = os.environ
    state_given, cache_given = top.get_opt_str("state_dir"), top.get_opt_str("cache_dir")
    sock_given = top.get_opt_str("control_socket")
    if state_given is not None:
        state_dir = _resolve(top.ctx, state_given)
    else:
        state_dir = Path(env.get("STATE_DIRECTORY", "/var/lib/grassd").split(":")[0])
    if cache_given is not None:
        cache_dir = _resolve(top.ctx, cache_given)
    else:
        cache_dir = default_cache_dir()  # this user's: never the state directory's
    if sock_given is not None:
        sock = _resolve(top.ctx, sock_given)
    elif env.get("RUNTIME_DIRECTORY"):
        sock = Path(env["RUNTIME_DIRECTORY"].split(":")[0]) / "control.sock"
    elif state_given is None and SYSTEM_RUNTIME_DIR.is_dir():
        sock = SYSTEM_RUNTIME_DIR / "control.sock"  # the service's socket, seen from a shell
    else:
        sock = state_dir / "control.sock"
    return state_dir, cache_dir, sock


def _parse_light(top: _Section, state_dir: Path) -> LightConfig:
    """``[light]`` with its ``[light.limits]`` and ``[light.modbus]`` tables; a relative
    ``inbox`` lies inside ``state_dir``."""
    lt = top.section("light", _schema(
        LightConfig,
        inbox=_F(str, check=_non_empty),
        lux=_F(str, check=_one_of("manifest", "modbus")),
        modbus=_F(dict), settle_s=_F(float, check=_non_negative),
        incomplete_timeout_s=_F(float, check=_positive),
        lux_wait_s=_F(float, check=_non_negative),
        future_tolerance_s=_F(float, check=_non_negative),
        hdri_flip=_F(bool),
        hdri_rotation_deg=_F(float, check=_between(-360, 360, " degrees")),
        limits=_F(dict),
    ))
    # left out, [light.limits] is the dataclass's default
    limits = _parse_light_limits(lt) if lt.given("limits") else lt.get_as("limits", BundleLimits)
    modbus = _parse_modbus(lt)
    if lt.get_str("lux") == "modbus" and modbus is None:
        raise lt.error("lux", "lux = \"modbus\" needs a [light.modbus] table")
    inbox = Path(os.path.expandvars(os.path.expanduser(lt.get_str("inbox"))))
    return LightConfig(inbox=inbox if inbox.is_absolute() else state_dir / inbox,
                       lux=lt.get_str("lux"), modbus=modbus, settle_s=lt.get_float("settle_s"),
                       incomplete_timeout_s=lt.get_float("incomplete_timeout_s"),
                       lux_wait_s=lt.get_float("lux_wait_s"),
                       future_tolerance_s=lt.get_float("future_tolerance_s"),
                       hdri_flip=lt.get_bool("hdri_flip"),
                       hdri_rotation_deg=lt.get_float("hdri_rotation_deg"), limits=limits)


def _parse_light_limits(light: _Section) -> BundleLimits:
    """``[light.limits]``: caps on a bundle (KiB, MiB, entries)."""
    return light.section("limits", _schema(
        BundleLimits,
        manifest_kib=_F(int, check=_between(1, 16 * 1024, " KiB")),
        file_mib=_F(int, check=_between(1, 64 * 1024, " MiB")),
        bundle_mib=_F(int, check=_between(1, 256 * 1024, " MiB")),
        entries=_F(int, check=_between(2, 100_000)),
    )).fill(BundleLimits)


def _parse_modbus(light: _Section) -> ModbusConfig | None:
    """``[light.modbus]``: the lux sensor's link and register map (None without the table)."""
    m = light.opt_section("modbus", _schema(
        ModbusConfig,
        mode=_F(str, check=_one_of(*MODBUS_MODES)), host=_F(str),
        port=_F(int, check=_between(1, 65535)), serial_port=_F(str),
        baud=_F(int, check=_positive), unit=_F(int, check=_between(0, 247)),
        function_code=_F(int, check=_one_of(3, 4)),
        register=_F(int, check=_between(0, 65535)), words=_F(int, check=_one_of(1, 2)),
        word_order=_F(str, check=_one_of(*WORD_ORDERS)),
        value_type=_F(str, check=_one_of(*VALUE_TYPES)),
        scale=_F(float, check=lambda v: None if v != 0 else "must not be 0"),
        offset=_F(float), timeout_s=_F(float, check=_positive),
        retries=_F(int, check=_between(0, 20)),
    ))
    if m is None:
        return None
    if m.get_str("mode") == "rtu" and not m.get_str("serial_port"):
        raise m.error("serial_port",
                      "required when mode = \"rtu\" (e.g. /dev/serial/by-id/usb-...)")
    if m.get_str("value_type") == "float" and m.get_int("words") != 2:
        raise m.error("words", "value_type = \"float\" needs words = 2")
    return m.fill(ModbusConfig)


def _parse_schedule(top: _Section) -> ScheduleConfig:
    """``[schedule]``: a run at least every ``interval_s`` seconds and/or on each new bundle."""
    sc = top.section("schedule", _schema(
        ScheduleConfig, interval_s=_F(float, check=_non_negative), on_new_bundle=_F(bool),
    ))
    if sc.get_float("interval_s") == 0 and not sc.get_bool("on_new_bundle"):
        raise sc.error("on_new_bundle",
                       "with interval_s = 0 too, bundles in the inbox would never be picked up: "
                       "set on_new_bundle = true or interval_s > 0")
    return sc.fill(ScheduleConfig)


def _parse_simulation(top: _Section, display: DisplayConfig) -> SimulationConfig:
    """``[simulation]``; its ``lengths`` (a count, or mm) lie within the green range of the
    ``display``'s pixel (0 mm to its ``green_max_mm``)."""
    si = top.section("simulation", _schema(
        SimulationConfig, samples=_F(int, check=_between(1, 1 << 20)),
        seed=_F(int, check=_non_negative), layouts=_F(int, check=_between(1, 64)),
        transport=_F(str, check=_one_of(*TRANSPORTS)),
        spectral_share=_F(int, check=_between(1, 1024)),
        lengths=_F(int | list, 11, hint="an integer count or an array of mm"),  # parsed below
    ))
    return SimulationConfig(samples=si.get_int("samples"), seed=si.get_int("seed"),
                            layouts=si.get_int("layouts"), transport=si.get_str("transport"),
                            spectral_share=si.get_int("spectral_share"),
                            lengths_mm=_simulation_lengths(si, 0.0, display.green_max_mm))


def _simulation_lengths(si: _Section, lo: float, hi: float) -> tuple[float, ...]:
    """``[simulation] lengths``: a count of evenly spaced lengths from ``lo`` to ``hi`` mm, or
    a strictly increasing array of mm within them."""
    raw = si.get_value("lengths")
    if isinstance(raw, int) and not isinstance(raw, bool):
        if not 3 <= raw <= 1000:
            raise si.error("lengths", f"count must be between 3 and 1000, got {raw}")
        return tuple(lo + (hi - lo) * k / (raw - 1) for k in range(raw))
    if isinstance(raw, list):
        lpath = si.path + ("lengths",)
        vals = [_check_type(si.ctx, lpath, x, float) for x in raw]
        if len(vals) < 3:
            raise si.error("lengths", f"needs at least 3 lengths, got {len(vals)}")
        if any(b <= a for a, b in zip(vals, vals[1:], strict=False)):
            raise si.error("lengths", "lengths must be strictly increasing (mm)")
        if vals[0] < lo or vals[-1] > hi:
            raise si.error("lengths", f"lengths must lie within {lo}-{hi} mm")
        return tuple(vals)
    raise si.error("lengths", f"must be an integer count or an array of mm, got {raw!r}")


def _parse_operator(top: _Section) -> tuple[MetricsConfig, AlertsConfig]:
    """``[metrics]`` and ``[alerts]`` (see their dataclasses)."""
    m = top.section("metrics", _schema(MetricsConfig, textfile=_F(str, check=_non_empty)))
    written = m.get_opt_str("textfile")
    textfile = None if written is None else _resolve(top.ctx, written)
    if textfile is not None and textfile.suffix != ".prom":
        raise m.error("textfile", "must end in .prom (node_exporter's textfile "
                      f"collector reads only *.prom files), got {textfile.name!r}")
    a = top.section("alerts", _schema(
        AlertsConfig, command=_F(str, check=_shell_words),
        min_interval_s=_F(float, check=_non_negative), timeout_s=_F(float, check=_positive),
    ))
    return MetricsConfig(textfile=textfile), a.fill(AlertsConfig)


def _shell_words(v: str) -> str | None:
    try:
        words = shlex.split(v)
    except ValueError as exc:
        return f"cannot be split into words like a shell line: {exc}"
    return None if words else "must name a program"


def _measure_section(top: _Section, has_capture: bool) -> MeasureConfig | None:
    """``[measure]``, validated by :mod:`grassd.daemon.measure.config` (imported lazily)."""
    from grassd.daemon.measure.config import parse_measure

    return parse_measure(top, has_capture)


def _content_section(top: _Section) -> ContentConfig | None:
    """``[content]``, validated by :mod:`grassd.daemon.content.config` (imported only when
    the section is there)."""
    if top.get_value("content") is None:
        return None
    from grassd.daemon.content.config import parse_content

    return parse_content(top)


def _capture_section(top: _Section) -> CaptureConfig | None:
    """``[capture]``, validated by :mod:`grassd.daemon.camera.config` (imported lazily:
    only a configuration with a capture station needs it)."""
    from grassd.daemon.camera.config import parse_capture

    return parse_capture(top)


def _parse_tables_audience(top: _Section) -> tuple[TablesConfig, AudienceConfig | None]:
    """``[tables]`` and the optional ``[audience]`` region (see their dataclasses)."""
    tables = top.section("tables", _schema(
        TablesConfig,
        granularity=_F(str, check=_one_of("global", "controller", "pixel")),
        eye=_F(str, check=_one_of("world", "pixel")),
        group_tolerance_deg=_F(float, check=_between(0.0, 90.0, " degrees")),
        distance_tolerance=_F(float, check=_between(1e-3, 10.0)),
        check_groups=_F(int, check=_between(-1, 4096)),
        layout=_F(str, check=_one_of("auto", "shared", "per_pixel")),
    )).fill(TablesConfig)

    def polygon_check(v: list[TomlValue]) -> str | None:
        ok = len(v) >= 3 and all(isinstance(p, list) and _numbers(2)(p) is None for p in v)
        return None if ok else "must be an array of at least 3 [x, y] points in metres"

    a = top.opt_section("audience", _schema(
        AudienceConfig,
        polygon=_F(list, check=polygon_check), h_cm=_F(list, check=_numbers(2)),
        ground_samples=_F(int, check=_between(1, 10000)),
        height_samples=_F(int, check=_between(1, 100)),
        objective=_F(str, check=_one_of("mean", "worst")),
    ))
    if a is None:
        return tables, None
    lo, hi = a.get_floats("h_cm")
    if not 10 <= lo <= hi <= 1000:
        raise a.error("h_cm", f"must be [low, high] with 10 <= low <= high <= "
                      f"1000 cm, got {a.get_list('h_cm')}")
    poly = tuple((x, y) for x, y in a.get_float_rows("polygon"))
    xs, ys = [p[0] for p in poly], [p[1] for p in poly]
    area = 0.5 * abs(sum(xs[i] * ys[i - 1] - xs[i - 1] * ys[i] for i in range(len(poly))))
    if area <= 1e-6:
        raise a.error("polygon", "has no area; list its corners in order")
    return tables, AudienceConfig(polygon=poly, h_cm=(lo, hi),
                                  ground_samples=a.get_int("ground_samples"),
                                  height_samples=a.get_int("height_samples"),
                                  objective=a.get_str("objective"))


# --------------------------------------------------------------------------- public API


def parse_config(text: str, *, source: str = "<string>", base_dir: Path | None = None) -> Config:
    """Parse and validate TOML ``text``; relative paths resolve against ``base_dir`` (or cwd)."""
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        m = re.search(r"line (\d+)", str(exc))
        raise ConfigError(f"TOML syntax error: {exc}", line=int(m.group(1)) if m else None,
                          path=source) from None
    ctx = _Ctx(text, source, base_dir or Path.cwd())
    return _parse(data, ctx)


def load_config(path: str | os.PathLike[str]) -> Config:
    """Read and validate the configuration file at ``path``."""
    p = Path(path)
    try:
        raw = p.read_bytes()
    except FileNotFoundError:
        raise ConfigError("configuration file not found (pass --config FILE)",
                          path=str(p)) from None
    except OSError as exc:
        raise ConfigError(f"cannot read configuration: {exc.strerror}", path=str(p)) from None
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ConfigError(f"not UTF-8 text (byte {exc.start})", path=str(p)) from None
    return parse_config(text, source=str(p), base_dir=p.resolve().parent)


def default_config_text() -> str:
    """The embedded default configuration (``daemon/core/config/default.toml``) as text."""
    # beside this module, in the package (importlib.resources costs 40 ms of start-up)
    return Path(__file__).with_name("default.toml").read_text("utf-8")


def load_default_config(**overrides: Any) -> Config:
    """The embedded default configuration, paths resolved against the current directory."""
    cfg = parse_config(default_config_text(), source="<embedded default.toml>")
    return cfg.replace(**overrides) if overrides else cfg


def resolve_config(path: str | os.PathLike[str] | None,
                   state_dir: str | os.PathLike[str] | None = None) -> Config:
    """The configuration a command runs with: ``path``, else :data:`DEFAULT_CONFIG_PATH` when
    it exists, else the embedded default; with ``state_dir`` (made absolute) instead of the
    configured one when given."""
    if path is not None:
        cfg = load_config(path)
    elif DEFAULT_CONFIG_PATH.exists():
        cfg = load_config(DEFAULT_CONFIG_PATH)
    else:
        cfg = load_default_config()
    return cfg.with_state_dir(Path(state_dir).absolute()) if state_dir else cfg


def not_used_by_the_daemon(cfg: Config) -> list[str]:
    """Settings that ``grassd run`` does not act on, as warnings (empty when all are used).

    The daemon honours ``[tables] granularity`` (a table per controller or per pixel) and
    ``[audience]`` (tables from the region instead of ``[[viewpoints]]``):
    :mod:`grassd.daemon.core.calibration.units`. With ``[audience]`` every eye is a world
    position, so ``[tables] eye = "pixel"`` has no meaning there.
    """
    notes = []
    if cfg.audience is not None and cfg.tables.eye != "world":
        notes.append(f"tables.eye = {cfg.tables.eye!r} is ignored with [audience]: the region's "
                     "eyes are world positions, every pixel seen from its own direction")
    return notes
