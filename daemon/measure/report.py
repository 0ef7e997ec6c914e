"""A measurement's report (``grassd measure``): its JSON, written with a self-contained HTML page
beside it (:mod:`grassd.daemon.measure.report_page`), the reports read back, and their trend
over months.

Files (:class:`~grassd.daemon.core.store.layout.StateLayout`): ``measure/<id>.json`` and
``measure/<id>.html``, ``<id>`` the measurement's UTC start (``YYYYmmddTHHMMSSZ``). Both are
written atomically; the JSON holds no NaN or Inf (a non-finite number is written as null).

Units: lengths mm, colour differences CIEDE2000 (dE00), gains as factors (1 = the model),
illuminance lux, camera position m, pose residual degrees.
"""

from __future__ import annotations

import json
import logging
import math
import re
from collections.abc import Mapping, Sequence
from datetime import UTC, datetime
from pathlib import Path
from typing import Any, Literal, NotRequired, Required, TypedDict, cast

import numpy as np

from grassd.daemon.core.calibration.variation import PixelVariation
from grassd.daemon.core.store.atomic import atomic_write_json, atomic_write_text
from grassd.daemon.core.store.layout import StateLayout
from grassd.daemon.measure.evidence import EvidenceSummaryJson

log = logging.getLogger(__name__)

#: past measurements read for the trend in a report
TREND_MEASUREMENTS = 1000

_ID_RE = re.compile(r"^[0-9A-Za-z_-]+$")



# -- the report's JSON ------------------------------------------------------------------------


class Uniformity(TypedDict):
    """Uniformity of the display at the checked levels
    (:data:`~grassd.daemon.measure.run.CHECK_LEVELS`; the report's ``before_detail`` and
    ``after_detail``, :mod:`grassd.daemon.measure.run`): the worst pixel pair at the mid level
    (dE00 and the two pixels), the OGCD spread and mean per level (dE00)."""

    worst_pair_de00: float
    worst_pair: list[int]
    ogcd_spread_de00: list[float]
    mean_ogcd_de00: list[float]


class UniformityReport(TypedDict):
    """The report's ``uniformity``: the worst pixel pair at ``level`` before and after the
    correction (dE00), their ratio (None when after is 0) and the detail at ``levels``."""

    level: int
    levels: list[int]
    before: float
    after: float
    improvement: float | None
    before_detail: Uniformity
    after_detail: Uniformity


class CameraViewpoint(TypedDict):
    """The camera's position as a viewpoint of the display (cm, m, degrees)."""

    h_cm: float
    d_m: float
    theta_deg: float


class CameraReport(TypedDict):
    """The report's ``camera``: its URL, solved position (m, world), pose residual (rms
    degrees) and that position as a viewpoint."""

    url: str | None
    position_m: list[float]
    rms_deg: float
    viewpoint: CameraViewpoint


class LightReport(TypedDict):
    """The report's ``light``: the panorama and the lux read at every shot."""

    hdri: str
    lux: list[float]


class PixelReport(PixelVariation):
    """One pixel of the report's ``pixels``: its fitted departure and the fit's rms CIELAB
    residual with it (``rms_lab``) and with the model pixel (``rms_lab_model``)."""

    rms_lab: float
    rms_lab_model: float


class CharacteristicReport(TypedDict):
    """The report's ``characteristic``: every pixel's OGCD (dE00) at the patterns' lengths
    (mm) as measured, as the model predicts and as fitted, and the largest differences."""

    lengths_mm: list[float]
    measured_ogcd: list[list[float]]
    predicted_ogcd: list[list[float]]
    fitted_ogcd: list[list[float]]
    max_error_predicted_de00: float
    max_error_fitted_de00: float


class VerdictReport(TypedDict):
    """The report's ``verdict``: "within tolerance" or "recalibrate", the tolerance (dE00)
    and the reason in words."""

    state: Literal["within tolerance", "recalibrate"]
    tolerance_de00: float
    reason: str


class TablesReport(TypedDict):
    """The report's ``tables``: their granularity and source; once kept or refused, the run
    they were committed as (None: refused), its status, and which controllers took them."""

    granularity: str
    nominal_source: str
    run_id: NotRequired[int | None]
    status: NotRequired[str]
    pushed: NotRequired[list[bool]]


#: How a measurement ended (the report's ``status``).
MeasurementStatus = Literal["ok", "refused", "failed", "interrupted"]


class MeasurementReport(TypedDict, total=False):
    """A measurement's report (``measure/<id>.json``, ``grassd measure --json``, the control
    socket's ``measure``): every key of a successful one; a failed or interrupted one holds
    ``measurement``, ``trigger``, ``started_at``, ``finished_at``, ``status`` and ``error``, a
    refused one also ``evidence`` and ``tables`` (and all the rest when its photos were
    judged). ``report``: its JSON file's path; ``seconds``: the wall time of each part of the
    measurement (``calibrate``, ``photos_before``, ``analyse_and_after``, ``total``). Read
    back, a non-finite number is None."""

    measurement: Required[str]
    trigger: str
    started_at: str
    finished_at: str
    status: MeasurementStatus
    error: str
    report: str
    camera: CameraReport
    light: LightReport
    patterns_mm: list[float]
    shape: list[int]
    display_colour_balance: list[float]
    pixels: list[PixelReport]
    characteristic: CharacteristicReport
    uniformity: UniformityReport
    verdict: VerdictReport
    tables: TablesReport
    seconds: dict[str, float]
    evidence: EvidenceSummaryJson


class TrendPoint(TypedDict):
    """One successful measurement in the trend (:func:`trend`)."""

    measurement: str | None
    started_at: str | None
    before_de00: float | None
    after_de00: float | None
    verdict: str | None
    green_gain: float | None
    yellow_gain: float | None
    abs_offset_mm: float | None


# -- reading and writing ----------------------------------------------------------------------


def _finite(obj: Any, replaced: list[int]) -> Any:
    """``obj`` as plain JSON values, every NaN or Inf replaced by None (counted in
    ``replaced``); numpy arrays and scalars become lists and numbers."""
    if isinstance(obj, Mapping):
        return {k: _finite(v, replaced) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_finite(v, replaced) for v in obj]
    if isinstance(obj, float):
        if math.isfinite(obj):
            return obj
        replaced[0] += 1
        return None
    tolist = getattr(obj, "tolist", None)
    if callable(tolist) and not isinstance(obj, str | bytes):
        return _finite(tolist(), replaced)
    return obj


def write_report(layout: StateLayout, report: MeasurementReport) -> Path:
    """Write the measurement ``report`` (a successful one, or a failed or interrupted one that
    holds only ``measurement``, ``trigger``, ``started_at``, ``finished_at``, ``status`` and
    ``error``) as ``layout.measure/<measurement>.json`` and its HTML page ``<measurement>.html``
    beside it, both atomically; returns the JSON's path.

    A non-finite number (NaN, Inf) is written as null, with a warning. The HTML includes the
    trend over the measurements in ``layout.measure`` (this one included). Raises ValueError
    when ``report["measurement"]`` is not a plain file stem, OSError when a file cannot be
    written."""
    mid = str(report.get("measurement", ""))
    if not _ID_RE.match(mid):
        raise ValueError(f"measurement id {mid!r} is not a plain file name stem")
    replaced = [0]
    clean = _finite(dict(report), replaced)
    if replaced[0]:
        log.warning("measurement %s: %d non-finite number(s) written as null", mid,
                    replaced[0])
    path = layout.measure / f"{mid}.json"
    atomic_write_json(path, clean)
    past = load_reports(layout, TREND_MEASUREMENTS)
    from grassd.daemon.measure.report_page import report_page

    atomic_write_text(path.with_suffix(".html"), report_page(clean, past, path.name))
    return path


def load_reports(layout: StateLayout, limit: int | None = None) -> list[MeasurementReport]:
    """The measurements' JSON reports in ``layout.measure``, oldest first: the newest ``limit``
    of them (None: all). Each gets the key ``"report"``, its JSON file's path, where it has
    none. A file that cannot be read or is not a JSON object is skipped with a warning."""
    paths = layout.measurement_reports()
    if limit is not None:
        paths = paths[-limit:] if limit > 0 else []
    out: list[MeasurementReport] = []
    for p in paths:
        try:
            doc = json.loads(p.read_text(encoding="utf-8"))
        except (OSError, ValueError) as exc:
            log.warning("measurement report %s skipped: %s", p, exc)
            continue
        if not isinstance(doc, dict):
            log.warning("measurement report %s skipped: not a JSON object", p)
            continue
        rep = cast(MeasurementReport, doc)  # its readers take every part as they find it
        rep.setdefault("report", str(p))
        out.append(rep)
    return out


def finite_number(v: float | None) -> float | None:
    """A report's number ``v`` as a finite float, None for anything else (missing, null, NaN;
    text or a bool in a report of another shape)."""
    if isinstance(v, bool) or not isinstance(v, int | float):
        return None
    f = float(v)
    return f if math.isfinite(f) else None


def _mean(values: Sequence[float | None], absolute: bool = False) -> float | None:
    nums = [x for x in (finite_number(v) for v in values) if x is not None]
    if not nums:
        return None
    return float(np.mean(np.abs(nums) if absolute else nums))


def pixels_of(report: MeasurementReport) -> list[PixelReport]:
    """The report's pixels that are JSON objects ([] where it has none)."""
    px = report.get("pixels")
    return [p for p in px if isinstance(p, Mapping)] if isinstance(px, list) else []


def _state(report: MeasurementReport) -> str | None:
    """The report's verdict (``verdict.state``), None without one."""
    v = v if isinstance(v := report.get("verdict", {}), Mapping) else {}
    return v.get("state")


def trend(reports: Sequence[MeasurementReport]) -> list[TrendPoint]:
    """One point per successful measurement (``status`` "ok") of ``reports``, in their order:
    ``measurement`` (id), ``started_at`` (ISO text), ``before_de00`` and ``after_de00`` (the
    uniformity: worst pixel pair at the mid level, dE00, before and after the correction),
    ``verdict`` ("within tolerance" / "recalibrate"), ``green_gain`` and ``yellow_gain`` (the
    pixels' mean gains, factors) and ``abs_offset_mm`` (the pixels' mean |length offset|, mm).
    A value the report lacks is None. Gains drifting from 1 and offsets growing over months
    show the display fading."""
    out: list[TrendPoint] = []
    for r in reports:
        if r.get("status") != "ok":
            continue
        px = pixels_of(r)
        u = u if isinstance(u := r.get("uniformity", {}), Mapping) else {}
        out.append({
            "measurement": r.get("measurement"), "started_at": r.get("started_at"),
            "before_de00": finite_number(u.get("before")),
            "after_de00": finite_number(u.get("after")),
            "verdict": _state(r),
            "green_gain": _mean([p.get("green_gain") for p in px]),
            "yellow_gain": _mean([p.get("yellow_gain") for p in px]),
            "abs_offset_mm": _mean([p.get("length_offset_mm") for p in px], absolute=True),
        })
    return out


def epoch_of(iso: str | None) -> float | None:
    """Epoch seconds of an ISO 8601 time (a report's ``started_at``), None when it is not one
    (a time without zone is taken as UTC)."""
    if not isinstance(iso, str):
        return None
    try:
        t = datetime.fromisoformat(iso.replace("Z", "+00:00"))
    except ValueError:
        return None
    if t.tzinfo is None:
        t = t.replace(tzinfo=UTC)
    return t.timestamp()


def verdict_class(report: MeasurementReport) -> str:
    """The report's headline as a CSS class: "within" (within tolerance), "recalibrate", or
    "failed" (failed, interrupted, or no verdict)."""
    if report.get("status") != "ok":
        return "failed"
    state = _state(report)
    return {"within tolerance": "within", "recalibrate": "recalibrate"}.get(state or "",
                                                                            "failed")


def headline(report: MeasurementReport) -> str:
    """The report's verdict in words: "within tolerance", "recalibrate", or the status of a
    measurement that did not finish ("failed", "interrupted")."""
    if report.get("status") != "ok":
        return str(report.get("status") or "unknown")
    return str(_state(report) or "no verdict")


