"""Sweeps: characteristics over many conditions, run on local processes or a Dask cluster.

A sweep crosses HDRIs x times of day x viewpoints x pixel specs (:class:`Condition`) under one set
of shared settings (:class:`SweepSpec`). Each condition is one task: build the light, trace the
display's centre pixel (neighbours present) from the viewpoint with
:func:`grassd.daemon.core.calibration.simulation.simulate_curve`, derive the OGCD range, the
linearity of OGCD vs length (R^2) and the R^2 after an 8-bit table. Results go to one tidy SQLite
table as they arrive (one transaction per task), so a sweep stopped at any point resumes from its
partial output: finished tasks are skipped (:func:`run_sweep`).

Light for a time of day (site latitude/longitude, date, IANA time zone): the sun's position by
NREL SPA (:func:`grassd.sim.sun.sun_position`); the clear-sky global horizontal irradiance by
Haurwitz (1945), ``GHI = 1098 cos z exp(-0.057 / cos z)`` W/m^2 (``pvlib.clearsky.haurwitz``),
as lux through :data:`grassd.sim.sun.GLOBAL_EFFICACY_LM_W`; its direct share by the Erbs
decomposition (:func:`grassd.sim.sun.clear_sky_direct_fraction`). The HDRI gives the sky's
shape and is scaled to the diffuse part; the direct part is a directional sun. A sun below
3 deg gives ``night_lux`` of sky light only. (An HDRI with its own bright sun then holds two suns:
use sky panoramas, or no ``times`` and a fixed ``lux``.)

Determinism: a task's seed is a hash of its condition and the shared settings, never of where
or when it runs, and the renderer is bit-reproducible for a seed, so a sweep on a Dask cluster
equals the local sweep bit for bit (on the same CPU architecture).

Executors: ``workers`` local processes (spawned; each initialises Taichi once, with
``cpu_count // workers`` threads, and keeps its compiled kernels), or a dask.distributed cluster
(``compute``, a ``[compute]`` section: ``scheduler = "tls://HOST:8786"`` and the site's TLS
files): each Dask worker process initialises Taichi on its first task and keeps it
(module-level renderer). A task lost with a killed worker is recomputed by Dask (``retries``
extra attempts for tasks that raise). The cluster is reached as the daemon reaches it
(:mod:`grassd.daemon.compute.dask_client`: mutual TLS, ``tcp://`` only with
``allow_insecure``, Dask's msgpack serializer only). A task receives a :class:`SweepJob` (the
shared settings and its condition; HDRI paths travel as paths: every worker must read them at
the same path, a shared filesystem) and answers a :class:`ConditionResult` in the declared form
of :mod:`grassd.daemon.compute.wire`, checked on arrival (:func:`check_arrival`) before it
is stored.
"""

from __future__ import annotations

import datetime as dt
import hashlib
import json
import math
import os
import socket
import sqlite3
import threading
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Final, TypedDict

import numpy as np
from numpy.typing import NDArray

from grassd.daemon.core.errors import ComputeResultRefused, ComputeUnavailable, DaemonError
from grassd.daemon.offline.sweep_config import (
    DEFAULT_CONTRAST_THRESHOLD,
    SWEEP_RETRIES,
    SWEEP_WORKERS,
    SweepSpec,
)
from grassd.sim.light_input import LightInput
from grassd.sim.scene import RenderSettings

if TYPE_CHECKING:
    from grassd.daemon.compute.config import ComputeConfig
    from grassd.daemon.compute.wire import ErrorAnswer, ResultAnswer

SCHEMA_VERSION = 1


class SweepError(DaemonError):
    """A sweep cannot run or resume (bad spec, output of another sweep, unreachable cluster)."""


# ---------------------------------------------------------------------- conditions


@dataclass(frozen=True)
class Condition:
    """One task's condition: ``hdri`` path, ``time`` "HH:MM" local ("" = fixed lux, no sun),
    viewpoint ``view`` = (h cm, d m, theta deg), pixel spec ``pixel`` name and its
    ``PixelSpec`` field overrides as sorted (name, value) pairs."""

    hdri: str
    time: str
    view: tuple[float, float, float]
    pixel: str = "default"
    pixel_fields: tuple[tuple[str, float | int], ...] = ()

    def key(self, spec: SweepSpec) -> str:
        """Stable task id: SHA-256 of the condition and the shared settings (hex, 20 chars)."""
        doc = json.dumps([asdict(self), spec.to_json()], sort_keys=True)
        return hashlib.sha256(doc.encode()).hexdigest()[:20]

    def seed(self, spec: SweepSpec) -> int:
        """Deterministic task seed in 0..2^31-1 (from :meth:`key`)."""
        return int(self.key(spec), 16) % (2**31 - 1)


def parse_pixel_option(text: str) -> tuple[str, tuple[tuple[str, float | int], ...]]:
    """``NAME`` or ``NAME:field=value,field=value`` (PixelSpec's number fields).

    Each value takes its field's type: ``int`` fields (``slit_count``, ``layout_seed``) take
    whole numbers only (``3``, also ``3.0``), ``float`` fields any finite number. Raises
    :class:`SweepError` naming the field and what it accepts.

    >>> parse_pixel_option("splay10:splay_deg=10")
    ('splay10', (('splay_deg', 10.0),))
    >>> parse_pixel_option("l2:layout_seed=2")
    ('l2', (('layout_seed', 2),))
    """
    name, _, rest = text.partition(":")
    if not name.strip():
        raise SweepError(f"pixel spec {text!r} needs a name, e.g. splay10:splay_deg=10")
    kinds = _pixel_number_fields()
    pairs = []
    for part in filter(None, (p.strip() for p in rest.split(","))):
        k, eq, v = part.partition("=")
        k, v = k.strip(), v.strip()
        if not eq or k not in kinds:
            raise SweepError(f"pixel spec {text!r}: {part!r} must be FIELD=NUMBER with FIELD "
                             f"one of {', '.join(sorted(kinds))}")
        pairs.append((k, _pixel_number(text, k, v, kinds[k])))
    return name.strip(), tuple(sorted(pairs))


def _pixel_number_fields() -> dict[str, type]:
    """PixelSpec's fields that ``--pixel`` can set -> their type (int or float); the sRGB
    triples are not numbers and stay with the config file."""
    from dataclasses import fields

    from grassd.sim.scene import PixelSpec

    out: dict[str, type] = {}
    for f in fields(PixelSpec):
        kind = {"int": int, "float": float}.get(f.type if isinstance(f.type, str)
                                                else getattr(f.type, "__name__", ""))
        if kind is not None:
            out[f.name] = kind
    return out


def _pixel_number(text: str, field: str, value: str, kind: type) -> float | int:
    """``value`` of PixelSpec ``field`` (of type ``kind``) parsed; :class:`SweepError` if it
    is not a finite number, or for an int field (a count or a seed) not a whole number >= 0."""
    try:
        x = float(value)
    except ValueError:
        x = math.nan
    if not math.isfinite(x):
        raise SweepError(f"pixel spec {text!r}: {field}={value!r} is not a number")
    if kind is not int:
        return x
    if not x.is_integer() or x < 0:
        raise SweepError(f"pixel spec {text!r}: {field} must be a whole number >= 0 (an "
                         f"int), got {value!r}; e.g. {field}={max(math.floor(x), 0)}")
    try:
        return int(value)  # exact, also beyond float's 53 bits
    except ValueError:
        return int(x)  # "3.0", "1e3"


def conditions(hdris: Sequence[str], times: Sequence[str], views: Sequence[tuple],
               pixels: Sequence[tuple[str, tuple]] = (("default", ()),)) -> list[Condition]:
    """The cross product HDRIs x times x viewpoints x pixel specs, in that nesting order
    (an empty ``times`` means one fixed-lux light per HDRI)."""
    out = []
    for h in hdris:
        for t in (list(times) or [""]):
            for v in views:
                for name, fields_ in pixels:
                    out.append(Condition(str(h), t, tuple(float(x) for x in v), name,
                                         tuple(fields_)))
    return out


def check_conditions(spec: SweepSpec, conds: Sequence[Condition]) -> None:
    """Raise :class:`SweepError` naming what to fix before any work starts."""
    from grassd.sim.scene import DisplaySpec, PixelSpec, Viewpoint

    if not conds:
        raise SweepError("a sweep needs at least one HDRI and one viewpoint")
    RenderSettings(samples=spec.samples, replicates=spec.replicates,
                   max_bounces=spec.bounces, light_samples=spec.light_samples)
    if spec.replicates < 2:
        raise SweepError(f"replicates must be at least 2 (their spread gives the standard "
                         f"error), got {spec.replicates}")
    if len(spec.lengths_mm) < 3:
        raise SweepError("give at least 3 green lengths (e.g. 0:20:10)")
    if any(c.time for c in conds):
        if spec.latitude is None or spec.longitude is None or not spec.date:
            raise SweepError("times of day need --latitude, --longitude and --date")
        for c in conds:
            _local_time(spec, c.time)
    for c in {(c.pixel, c.pixel_fields) for c in conds}:
        DisplaySpec(PixelSpec(**dict(c[1])), spec.rows, spec.cols)
    for c in conds:
        Viewpoint(*c.view)
        if not Path(c.hdri).is_file():
            raise SweepError(f"HDRI {c.hdri} does not exist")
    keys = [c.key(spec) for c in conds]
    if len(set(keys)) != len(keys):
        raise SweepError("the sweep lists the same condition twice")


def _local_time(spec: SweepSpec, hhmm: str) -> dt.datetime:
    from zoneinfo import ZoneInfo, ZoneInfoNotFoundError

    try:
        day = dt.date.fromisoformat(spec.date or "")
        clock = dt.time.fromisoformat(hhmm)
        tz = ZoneInfo(spec.timezone)
    except (ValueError, ZoneInfoNotFoundError) as exc:
        raise SweepError(f"time {hhmm!r} on {spec.date!r} in {spec.timezone!r}: {exc} (use HH:MM,"
                         " YYYY-MM-DD and an IANA zone)") from None
    return dt.datetime.combine(day, clock, tzinfo=tz)


# --------------------------------------------------------------------------- light


def light_condition(spec: SweepSpec, hhmm: str, hdri: str | Path) -> LightInput:
    """Clear-sky light on ``hdri`` at local time ``hhmm`` (see the module docstring): the sun's
    compass azimuth/elevation [deg], the diffuse (ambient) and direct (sun, 0 below 3 deg)
    horizontal lux [lx]; fixed ``spec.lux`` without a sun if ``hhmm`` is ""."""
    if not hhmm:
        return LightInput(Path(hdri), float(spec.lux))
    from pvlib import clearsky

    from grassd.sim.sun import GLOBAL_EFFICACY_LM_W, clear_sky_direct_fraction, sun_position

    when = _local_time(spec, hhmm)
    az, el = sun_position(spec.latitude, spec.longitude, when)
    if el <= 3.0:
        return LightInput(Path(hdri), float(spec.night_lux), 0.0, az, el, timestamp=when)
    import pandas as pd

    ghi = float(clearsky.haurwitz(pd.Series([90.0 - el]))["ghi"].iloc[0])
    total = ghi * GLOBAL_EFFICACY_LM_W
    f = clear_sky_direct_fraction(total, el, when.timetuple().tm_yday)
    return LightInput(Path(hdri), max(total * (1 - f), spec.night_lux), total * f, az, el,
                      timestamp=when)


# --------------------------------------------------------------------------- task (workers)

_worker_lock = threading.Lock()
_worker: dict = {}


def _worker_state(threads: int | None = None) -> dict:
    """This process's Taichi backend and light cache, created on first use and kept for the
    life of the process (the renderers are :meth:`grassd.sim.renderer.Renderer.shared`'s, one
    per capacity, so kernels stay compiled)."""
    if not _worker:
        from grassd.sim import backend

        backend.init("cpu", threads=threads or int(os.environ.get("GRASSD_SWEEP_THREADS", 0))
                     or None)
        _worker.update(lights={})
    return _worker


def _renderer_for(n_pixels: int):
    from grassd.daemon.core.calibration.display_model import capacity_for
    from grassd.sim.renderer import Renderer

    _worker_state()  # Taichi first
    return Renderer.shared(capacity_for(n_pixels))


def init_worker(threads: int | None = None) -> None:
    """Process-pool initialiser: Taichi and the renderer once per worker process."""
    os.environ.setdefault("GRASSD_SWEEP_THREADS", str(threads or 0))
    with _worker_lock:
        _worker_state(threads)
        _renderer_for(1)


class SweepRow(TypedDict):
    """A :class:`ConditionResult` as :class:`SweepStore` stores it: its condition's columns
    (:data:`CONDITION_COLUMNS`) and its per-length columns as lists
    (:data:`LENGTH_COLUMNS`)."""

    key: str
    hdri: str
    time: str
    h_cm: float
    d_m: float
    theta_deg: float
    pixel: str
    seed: int
    sun_azimuth_deg: float | None
    sun_elevation_deg: float | None
    ambient_lux: float
    sun_lux: float
    ogcd_range: float
    linearity_r2: float | None
    table_r2_after: float | None
    max_ogcd_stderr: float
    seconds: float
    worker: str
    length_mm: list[float]
    ogcd: list[float]
    ogcd_stderr: list[float]
    L: list[float]
    a: list[float]
    b: list[float]


@dataclass(frozen=True)
class ConditionResult:
    """One traced condition: the condition (``key``, ``hdri``, ``time``, viewpoint ``h_cm`` /
    ``d_m`` / ``theta_deg`` [cm, m, deg], ``pixel``, ``seed``), its light (sun azimuth and
    elevation [deg], None without a time; ``ambient_lux`` and ``sun_lux`` [lx]), its figures
    (``ogcd_range`` [dE00], ``linearity_r2`` and ``table_r2_after``, None where undefined,
    ``max_ogcd_stderr`` [dE00]), where and how long it ran (``seconds`` [s], ``worker``), and
    per length (float64, one entry per length of the sweep): ``length_mm`` [mm], ``ogcd`` and
    ``ogcd_stderr`` [dE00], CIELAB ``L``, ``a``, ``b``. Its fields are the declared form a
    Dask worker answers in (:mod:`grassd.daemon.compute.wire`)."""

    key: str
    hdri: str
    time: str
    h_cm: float
    d_m: float
    theta_deg: float
    pixel: str
    seed: int
    sun_azimuth_deg: float | None
    sun_elevation_deg: float | None
    ambient_lux: float
    sun_lux: float
    ogcd_range: float
    linearity_r2: float | None
    table_r2_after: float | None
    max_ogcd_stderr: float
    seconds: float
    worker: str
    length_mm: NDArray[np.float64]
    ogcd: NDArray[np.float64]
    ogcd_stderr: NDArray[np.float64]
    L: NDArray[np.float64]
    a: NDArray[np.float64]
    b: NDArray[np.float64]

    def row(self) -> SweepRow:
        """The condition's columns and its per-length columns (lists) in plain Python types,
        as :class:`SweepStore` stores them."""
        def column(x: NDArray[np.float64]) -> list[float]:
            return np.asarray(x, np.float64).tolist()

        return SweepRow(
            key=self.key, hdri=self.hdri, time=self.time, h_cm=self.h_cm, d_m=self.d_m,
            theta_deg=self.theta_deg, pixel=self.pixel, seed=self.seed,
            sun_azimuth_deg=self.sun_azimuth_deg, sun_elevation_deg=self.sun_elevation_deg,
            ambient_lux=self.ambient_lux, sun_lux=self.sun_lux, ogcd_range=self.ogcd_range,
            linearity_r2=self.linearity_r2, table_r2_after=self.table_r2_after,
            max_ogcd_stderr=self.max_ogcd_stderr, seconds=self.seconds, worker=self.worker,
            length_mm=column(self.length_mm), ogcd=column(self.ogcd),
            ogcd_stderr=column(self.ogcd_stderr), L=column(self.L), a=column(self.a),
            b=column(self.b))


@dataclass(frozen=True)
class SweepJob:
    """What a Dask worker receives for one condition: the sweep's shared settings and the
    condition (its HDRI by path); nothing else."""

    spec: SweepSpec
    condition: Condition


def sweep_on_worker(job: SweepJob) -> ResultAnswer | ErrorAnswer:
    """The Dask task: trace ``job``'s condition (:func:`run_task`) and answer with its
    :class:`ConditionResult`, or with the grassd error it raised, in the declared form of
    :mod:`grassd.daemon.compute.wire`. Other errors propagate (Dask retries them)."""
    from grassd.daemon.compute.wire import ERROR_BASES, answer_of, error_answer

    try:
        return answer_of(run_task(job.spec, job.condition))
    except ERROR_BASES as exc:
        return error_answer(exc)


def check_arrival(spec: SweepSpec, cond: Condition, result: ConditionResult, where: str
                  ) -> None:
    """Checks of a result decoded from a worker's answer for ``cond``, before it is stored:
    it names ``cond`` (key, HDRI, time, viewpoint, pixel, seed), has one finite entry per
    length of ``spec`` in every per-length column and the sweep's lengths themselves, and
    finite figures. Raises :class:`ComputeResultRefused` naming what is wrong."""
    def refuse(msg: str) -> ComputeResultRefused:
        return ComputeResultRefused(f"{where} answered a sweep result that {msg}")

    want = (cond.key(spec), cond.hdri, cond.time, cond.view, cond.pixel, cond.seed(spec))
    got = (result.key, result.hdri, result.time, (result.h_cm, result.d_m, result.theta_deg),
           result.pixel, result.seed)
    if got != want:
        raise refuse(f"is for another condition ({got!r:.300}, not {want!r:.300})")
    n = len(spec.lengths_mm)
    for c in LENGTH_COLUMNS:
        if getattr(result, c).shape != (n,):
            raise refuse(f"has {c} of shape {getattr(result, c).shape}, not ({n},)")
    if not np.array_equal(result.length_mm, np.asarray(spec.lengths_mm, np.float64)):
        raise refuse("has other lengths than the sweep's")
    figures = [result.ambient_lux, result.sun_lux, result.ogcd_range, result.max_ogcd_stderr,
               result.seconds] + [x for x in (result.sun_azimuth_deg, result.sun_elevation_deg,
                                              result.linearity_r2, result.table_r2_after)
                                  if x is not None]
    if not all(math.isfinite(x) for x in figures):
        raise refuse("holds figures that are not finite")


def run_task(spec: SweepSpec, cond: Condition) -> ConditionResult:
    """Trace one condition (see :class:`ConditionResult` for what it holds and its units).
    Deterministic for (spec, cond), but for ``seconds`` and ``worker``."""
    from grassd.calib.errors import CalibError
    from grassd.calib.length_table import build_length_table, r_squared
    from grassd.daemon.core.calibration.simulation import simulate_curve
    from grassd.sim.scene import DisplaySpec, PixelSpec, Viewpoint

    t0 = time.perf_counter()
    with _worker_lock:  # one trace at a time per process (the renderer owns its fields)
        state = _worker_state()
        renderer = _renderer_for(spec.rows * spec.cols)
        light = light_condition(spec, cond.time, cond.hdri)
        lkey = (cond.hdri, cond.time, spec.to_json())
        lighting = state["lights"].get(lkey)
        if lighting is None:
            lighting = light.lighting()
            if len(state["lights"]) > 8:
                state["lights"].clear()
            state["lights"][lkey] = lighting
        display = DisplaySpec(PixelSpec(**dict(cond.pixel_fields)), spec.rows, spec.cols)
        settings = RenderSettings(samples=spec.samples, replicates=spec.replicates,
                                  max_bounces=spec.bounces, light_samples=spec.light_samples,
                                  seed=cond.seed(spec))
        pixel = (spec.rows // 2) * spec.cols + spec.cols // 2
        curve = simulate_curve(renderer, display, lighting, Viewpoint(*cond.view),
                               np.asarray(spec.lengths_mm, float), settings,
                               pixel_index=pixel, target_stderr=spec.target_stderr)
    ogcd_range = float(curve.ogcd.max() - curve.ogcd[0])
    try:
        linearity = r_squared(curve.lengths_mm, curve.ogcd)
    except CalibError:
        linearity = None
    try:
        from grassd.calib.characteristic import Characteristic, floor_stderr

        table_r2 = build_length_table(Characteristic(
            curve.lengths_mm, curve.ogcd, floor_stderr(curve.ogcd_stderr))).r2_after
    except CalibError:
        table_r2 = None
    def f64(x: NDArray[np.floating]) -> NDArray[np.float64]:
        return np.ascontiguousarray(x, np.float64)

    def number(x: float | None) -> float | None:
        return None if x is None else float(x)

    return ConditionResult(
        key=cond.key(spec), hdri=cond.hdri, time=cond.time,
        h_cm=cond.view[0], d_m=cond.view[1], theta_deg=cond.view[2],
        pixel=cond.pixel, seed=cond.seed(spec),
        sun_azimuth_deg=number(light.sun_azimuth_deg),
        sun_elevation_deg=number(light.sun_elevation_deg),
        ambient_lux=float(light.ambient_lux), sun_lux=float(light.sun_lux or 0.0),
        ogcd_range=ogcd_range, linearity_r2=number(linearity), table_r2_after=number(table_r2),
        max_ogcd_stderr=float(curve.ogcd_stderr.max()),
        seconds=time.perf_counter() - t0, worker=f"{socket.gethostname()}:{os.getpid()}",
        length_mm=f64(curve.lengths_mm), ogcd=f64(curve.ogcd),
        ogcd_stderr=f64(curve.ogcd_stderr), L=f64(curve.lab[:, 0]), a=f64(curve.lab[:, 1]),
        b=f64(curve.lab[:, 2]))


# --------------------------------------------------------------------------- output

#: Per-condition columns, repeated on every length row of the tidy table.
CONDITION_COLUMNS: Final = ("key", "hdri", "time", "h_cm", "d_m", "theta_deg", "pixel", "seed",
                     "sun_azimuth_deg", "sun_elevation_deg", "ambient_lux", "sun_lux",
                     "ogcd_range", "linearity_r2", "table_r2_after", "max_ogcd_stderr",
                     "seconds", "worker")
LENGTH_COLUMNS: Final = ("length_mm", "ogcd", "ogcd_stderr", "L", "a", "b")
#: Columns that depend on where/when a task ran (excluded when comparing runs).
RUN_COLUMNS = ("seconds", "worker")


class SweepStore:
    """The sweep's SQLite file: table ``results`` (tidy: one row per condition x length),
    view ``conditions`` (one row per condition), table ``meta`` (spec, schema version)."""

    def __init__(self, path: str | Path, spec: SweepSpec, restart: bool = False) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        if restart and self.path.exists():
            self.path.unlink()
        try:
            self.db = sqlite3.connect(self.path)
            self.db.execute("PRAGMA journal_mode=WAL")
            cols = ", ".join(f"{c} {_sql_type(c)}" for c in CONDITION_COLUMNS + LENGTH_COLUMNS)
            with self.db:
                self.db.execute("CREATE TABLE IF NOT EXISTS meta (name TEXT PRIMARY KEY, "
                                "value TEXT)")
                self.db.execute(f"CREATE TABLE IF NOT EXISTS results ({cols}, "
                                "PRIMARY KEY (key, length_mm))")
                ccols = ", ".join(CONDITION_COLUMNS)
                self.db.execute(f"CREATE VIEW IF NOT EXISTS conditions AS SELECT DISTINCT "
                                f"{ccols} FROM results")
                got = dict(self.db.execute("SELECT name, value FROM meta"))
        except sqlite3.DatabaseError as exc:
            raise SweepError(f"{self.path} is not a usable sweep database ({exc}); choose "
                             "another --out or pass --restart") from None
        if got and got.get("spec") != spec.to_json():
            raise SweepError(f"{self.path} holds a sweep with other settings; pass --restart "
                             "to overwrite it or choose another --out")
        with self.db:
            self.db.execute("INSERT OR REPLACE INTO meta VALUES ('spec', ?)", (spec.to_json(),))
            self.db.execute("INSERT OR REPLACE INTO meta VALUES ('schema', ?)",
                            (str(SCHEMA_VERSION),))

    def done_keys(self) -> set[str]:
        """Keys of the conditions already stored."""
        return {k for (k,) in self.db.execute("SELECT DISTINCT key FROM results")}

    def add(self, row: SweepRow) -> None:
        """Store one finished task atomically (all its length rows or none)."""
        n = len(row["length_mm"])
        cond = [row[c] for c in CONDITION_COLUMNS]
        rows = [cond + [row[c][i] for c in LENGTH_COLUMNS] for i in range(n)]
        marks = ", ".join("?" * (len(CONDITION_COLUMNS) + len(LENGTH_COLUMNS)))
        with self.db:
            self.db.executemany(f"INSERT OR REPLACE INTO results VALUES ({marks})", rows)

    def close(self) -> None:
        """Close the connection."""
        self.db.close()


def _sql_type(col: str) -> str:
    if col in ("key", "hdri", "time", "pixel", "worker"):
        return "TEXT"
    return "INTEGER" if col == "seed" else "REAL"


def read_results(path: str | Path, keys: Iterable[str] | None = None,
                 run_columns: bool = True) -> list[dict]:
    """Rows of ``results`` (optionally only ``keys``), ordered by key and length."""
    rows = _select(path, "SELECT * FROM results ORDER BY key, length_mm", keys)
    if not run_columns:
        for r in rows:
            for c in RUN_COLUMNS:
                r.pop(c, None)
    return rows


# --------------------------------------------------------------------------- executors


@dataclass
class SweepSummary:
    """What a :func:`run_sweep` call did: tasks in the sweep, skipped (already stored),
    computed now, wall seconds, tasks/s, executor description, output files."""

    total: int
    skipped: int
    computed: int
    seconds: float
    executor: str
    files: dict[str, str] = field(default_factory=dict)
    report: dict = field(default_factory=dict)

    @property
    def tasks_per_s(self) -> float:
        """Computed tasks per wall second."""
        return self.computed / self.seconds if self.seconds > 0 else 0.0


def run_sweep(spec: SweepSpec, conds: Sequence[Condition], out_dir: str | Path, *,
              workers: int = SWEEP_WORKERS, compute: ComputeConfig | None = None,
              restart: bool = False, threads_per_worker: int | None = None,
              retries: int = SWEEP_RETRIES, config_source: str | None = None,
              progress: Callable[[int, int], None] | None = None,
              on_result: Callable[[SweepRow], None] | None = None,
              plots: bool = True,
              contrast_threshold: float = DEFAULT_CONTRAST_THRESHOLD) -> SweepSummary:
    """Run every condition not yet in ``out_dir/sweep.sqlite``; write summary plots.

    ``workers`` local processes (``threads_per_worker`` Taichi CPU threads each; None: the
    cores split between them, 0: Taichi's default of all cores), or, when ``compute`` names a
    scheduler, its dask.distributed cluster (workers keep their own settings), secured as
    ``[compute]`` requires (``config_source`` names its file in errors). ``progress(done,
    total)`` after each stored task; ``on_result(row)`` too (tests use it to act mid-sweep).
    Raises :class:`SweepError` when the sweep cannot run or the cluster cannot run it,
    :class:`~grassd.daemon.core.errors.ConfigError` for a scheduler not secured as ``[compute]``
    requires, :class:`~grassd.daemon.core.errors.ComputeResultRefused` for a worker's answer not
    in the declared form (the results stored until then are kept).
    """
    scheduler = None if compute is None else compute.scheduler
    if compute is not None and scheduler is not None:
        from grassd.daemon.compute.dask_client import require_secured

        require_secured(compute, config_source, "this process")
    check_conditions(spec, conds)
    out = Path(out_dir)
    store = SweepStore(out / "sweep.sqlite", spec, restart=restart)
    t0 = time.perf_counter()
    try:
        done = store.done_keys()
        todo = [c for c in conds if c.key(spec) not in done]
        skipped = len(conds) - len(todo)
        count = [skipped]

        def stored(result: ConditionResult) -> None:
            row = result.row()
            store.add(row)
            count[0] += 1
            if on_result:
                on_result(row)
            if progress:
                progress(count[0], len(conds))

        if progress:
            progress(skipped, len(conds))
        if not todo:
            executor = "nothing to do"
        elif compute is not None and scheduler:
            executor = _run_dask(spec, todo, compute, retries, stored)
        else:
            executor = _run_local(spec, todo, workers, stored, threads_per_worker)
    finally:
        store.close()
    summary = SweepSummary(total=len(conds), skipped=skipped, computed=len(todo),
                           seconds=time.perf_counter() - t0, executor=executor,
                           files={"database": str(out / "sweep.sqlite")})
    if plots:
        summary.files.update(write_summary(out, [c.key(spec) for c in conds],
                                           contrast_threshold))
        summary.report = json.loads(Path(summary.files["summary_json"]).read_text())
    return summary


def _run_local(spec: SweepSpec, todo: Sequence[Condition], workers: int,
               stored: Callable[[ConditionResult], None], threads: int | None = None) -> str:
    import multiprocessing as mp
    from concurrent.futures import ProcessPoolExecutor, as_completed
    from concurrent.futures.process import BrokenProcessPool

    from grassd.sim.errors import require_renderer

    require_renderer()  # here, in one line, rather than as worker processes that died

    if workers < 1:
        raise SweepError(f"--workers must be >= 1, got {workers}")
    workers = min(workers, len(todo))
    # Taichi's offline kernel cache is keyed by its thread setting: one worker keeps the default
    # (all cores, the same key as the CLI and the daemon), several split the cores.
    if threads is None:
        threads = max(1, (os.cpu_count() or 1) // workers) if workers > 1 else 0
    ctx = mp.get_context("spawn")
    try:
        with ProcessPoolExecutor(workers, mp_context=ctx, initializer=init_worker,
                                 initargs=(threads,)) as pool:
            futures = [pool.submit(run_task, spec, c) for c in todo]
            for f in as_completed(futures):
                stored(f.result())
    except BrokenProcessPool as exc:
        raise SweepError(f"a local worker process died ({exc}); the finished tasks are stored: "
                         "run the same sweep again to resume") from None
    return f"{workers} local processes x {threads or os.cpu_count()} threads"


def _run_dask(spec: SweepSpec, todo: Sequence[Condition], compute: ComputeConfig,
              retries: int, stored: Callable[[ConditionResult], None]) -> str:
    """Each condition of ``todo`` as one task (:func:`sweep_on_worker`) on ``compute``'s
    cluster, reached through :func:`grassd.daemon.compute.dask_client.connect`; each
    answer decoded as a :class:`ConditionResult`, checked (:func:`check_arrival`) and
    ``stored`` as it arrives."""
    from grassd.daemon.compute.dask_client import connect, fetch_answer
    from grassd.daemon.compute.wire import read_answer

    scheduler = str(compute.scheduler)
    try:
        client = connect(compute)
    except ComputeUnavailable as exc:
        raise SweepError(str(exc)) from None
    try:
        from distributed import as_completed

        n_workers = len(client.scheduler_info().get("workers", {}))
        by_key = {f"grassd-sweep-{c.key(spec)}": c for c in todo}
        futures = [client.submit(sweep_on_worker, SweepJob(spec, c), key=k, retries=retries,
                                 pure=False) for k, c in by_key.items()]
        for f in as_completed(futures, loop=client.loop):
            try:
                answer, worker = fetch_answer(client, f, scheduler)
            except ComputeResultRefused:
                raise
            except ComputeUnavailable as exc:
                raise SweepError(f"{exc}; the finished tasks are stored: run the same sweep "
                                 "again to resume") from None
            where = f"Dask worker {worker or '(unknown)'} of {scheduler}"
            cond = by_key[f.key]
            result = read_answer(answer, ConditionResult, where)
            check_arrival(spec, cond, result, where)
            stored(result)
        return f"dask {scheduler} ({n_workers} workers)"
    finally:
        client.close()


# --------------------------------------------------------------------------- summary


def _condition_rows(db_path: Path, keys: Sequence[str]) -> list[dict]:
    """One dict per stored condition among ``keys`` (from the ``conditions`` view)."""
    return _select(db_path, "SELECT * FROM conditions", keys)


def _select(db_path: str | Path, sql: str, keys: Iterable[str] | None) -> list[dict]:
    """Rows of ``sql`` as dicts, only those whose ``key`` is in ``keys`` (all when None)."""
    db = sqlite3.connect(db_path)
    try:
        db.row_factory = sqlite3.Row
        rows = [dict(r) for r in db.execute(sql)]
    finally:
        db.close()
    if keys is None:
        return rows
    wanted = set(keys)
    return [r for r in rows if r["key"] in wanted]


def _hours(hhmm: str) -> float:
    h, m = hhmm.split(":")[:2]
    return int(h) + int(m) / 60


def summarise(rows: Sequence[dict], contrast_threshold: float = DEFAULT_CONTRAST_THRESHOLD
              ) -> dict:
    """Worst viewpoints (smallest OGCD range first) and the conditions whose OGCD range is
    below ``contrast_threshold`` [dE00] (where the display loses contrast)."""
    views: dict[tuple, list[dict]] = {}
    for r in rows:
        views.setdefault((r["h_cm"], r["d_m"], r["theta_deg"]), []).append(r)
    worst = sorted(({"view": list(v), "min_ogcd_range": min(x["ogcd_range"] for x in rs),
                     "mean_ogcd_range": float(np.mean([x["ogcd_range"] for x in rs])),
                     "min_linearity_r2": min((x["linearity_r2"] for x in rs
                                              if x["linearity_r2"] is not None), default=None)}
                    for v, rs in views.items()), key=lambda d: d["min_ogcd_range"])
    low = [{k: r[k] for k in ("hdri", "time", "h_cm", "d_m", "theta_deg", "pixel",
                              "ogcd_range", "sun_elevation_deg", "ambient_lux", "sun_lux")}
           for r in sorted(rows, key=lambda r: r["ogcd_range"])
           if r["ogcd_range"] < contrast_threshold]
    return {"conditions": len(rows), "contrast_threshold": contrast_threshold,
            "worst_viewpoints": worst, "low_contrast": low,
            "ogcd_range": [float(min((r["ogcd_range"] for r in rows), default=math.nan)),
                           float(max((r["ogcd_range"] for r in rows), default=math.nan))]}


def write_summary(out_dir: str | Path, keys: Sequence[str],
                  contrast_threshold: float = DEFAULT_CONTRAST_THRESHOLD) -> dict[str, str]:
    """Write ``summary.json`` and ``summary.png`` (OGCD range and linearity through the day,
    worst viewpoints, contrast loss) for the conditions ``keys`` stored in ``out_dir``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from grassd.daemon.core.store.atomic import atomic_save_figure, atomic_write_json

    out = Path(out_dir)
    rows = _condition_rows(out / "sweep.sqlite", keys)
    doc = summarise(rows, contrast_threshold)
    files = {"summary_json": str(atomic_write_json(out / "summary.json", doc))}
    timed = any(r["time"] for r in rows)
    fig, axes = plt.subplots(2, 2, figsize=(12, 8.5), dpi=100)
    series: dict[tuple, list[dict]] = {}
    for r in rows:
        series.setdefault((Path(r["hdri"]).stem, r["h_cm"], r["d_m"], r["theta_deg"],
                           r["pixel"]), []).append(r)
    for (hdri, h, d, th, pix), rs in sorted(series.items()):
        rs = sorted(rs, key=lambda r: r["time"])
        x = [_hours(r["time"]) if r["time"] else i for i, r in enumerate(rs)]
        label = f"{hdri} ({h:g},{d:g},{th:g}) {pix}"
        axes[0, 0].plot(x, [r["ogcd_range"] for r in rs], "o-", ms=3, label=label)
        axes[0, 1].plot(x, [np.nan if r["linearity_r2"] is None else r["linearity_r2"]
                            for r in rs], "o-", ms=3, label=label)
    xl = "local time [h]" if timed else "condition"
    axes[0, 0].set(xlabel=xl, ylabel="OGCD range [dE00]", title="OGCD range through the day")
    axes[0, 1].set(xlabel=xl, ylabel="R^2 of OGCD vs length",
                   title="linearity (before calibration)")
    if len(series) <= 12:
        axes[0, 0].legend(fontsize=6)
    worst = doc["worst_viewpoints"][:12]
    names = [f"({v['view'][0]:g},{v['view'][1]:g},{v['view'][2]:g})" for v in worst]
    axes[1, 0].barh(names[::-1], [v["min_ogcd_range"] for v in worst][::-1], color="tab:red",
                    label="lowest")
    axes[1, 0].barh(names[::-1], [v["mean_ogcd_range"] - v["min_ogcd_range"] for v in worst]
                    [::-1], left=[v["min_ogcd_range"] for v in worst][::-1], color="tab:gray",
                    alpha=0.5, label="to mean")
    axes[1, 0].set(xlabel="OGCD range [dE00]", title="worst viewpoints (h cm, d m, theta deg)")
    axes[1, 0].legend(fontsize=7)
    if timed:
        xs = [r["sun_elevation_deg"] for r in rows]
        xlabel = "sun elevation [deg]"
    else:
        xs = [r["ambient_lux"] + r["sun_lux"] for r in rows]
        xlabel = "horizontal illuminance [lx]"
    ys = [r["ogcd_range"] for r in rows]
    low = [y < contrast_threshold for y in ys]
    axes[1, 1].scatter([x for x, lo in zip(xs, low, strict=True) if not lo],
                       [y for y, lo in zip(ys, low, strict=True) if not lo], s=12, c="tab:blue",
                       label="ok")
    axes[1, 1].scatter([x for x, lo in zip(xs, low, strict=True) if lo],
                       [y for y, lo in zip(ys, low, strict=True) if lo], s=16, c="tab:red",
                       label=f"range < {contrast_threshold:g}")
    axes[1, 1].axhline(contrast_threshold, color="tab:red", lw=0.8, ls="--")
    axes[1, 1].set(xlabel=xlabel, ylabel="OGCD range [dE00]",
                   title=f"contrast loss: {len(doc['low_contrast'])} of {len(rows)} conditions")
    axes[1, 1].legend(fontsize=7)
    for ax in axes.ravel():
        ax.grid(alpha=0.3)
    fig.tight_layout()
    files["summary_png"] = str(atomic_save_figure(out / "summary.png", fig))
    plt.close(fig)
    return files
