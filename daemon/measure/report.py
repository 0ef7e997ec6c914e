"""A measurement's report (``grassd measure``): its JSON, a self-contained HTML page beside it,
the reports read back, and their trend over months.

Files (:class:`~grassd.daemon.core.store.layout.StateLayout`): ``measure/<id>.json`` and
``measure/<id>.html``, ``<id>`` the measurement's UTC start (``YYYYmmddTHHMMSSZ``). Both are
written atomically; the JSON holds no NaN or Inf (a non-finite number is written as null).

The HTML has no script and no external resource (styles inline, plots as inline SVG); every
text from the report is HTML-escaped and shown without control characters, as on the status
page (:mod:`grassd.daemon.core.monitoring.status_page`, whose style and helpers it shares). It
shows: the verdict with its reason (or the error of a failed measurement), the uniformity
before and after the correction (worst pixel pair at the mid level, improvement, OGCD spread
per level), the camera's pose, heat maps of every pixel's length offset and gains laid out as
the display (rows x cols), the per-pixel table, measured vs predicted vs fitted OGCD, and the
trend over the past measurements.

Units: lengths mm, colour differences CIEDE2000 (dE00), gains as factors (1 = the model),
illuminance lux, camera position m, pose residual degrees.
"""

from __future__ import annotations

import html
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
from grassd.daemon.core.monitoring.page_parts import CSS, Clock, esc, html_table, td
from grassd.daemon.core.monitoring.status_page import svg_trend
from grassd.daemon.core.store.atomic import atomic_write_json, atomic_write_text
from grassd.daemon.core.store.layout import StateLayout
from grassd.daemon.measure.evidence import EvidenceSummaryJson

log = logging.getLogger(__name__)

#: past measurements read for the trend in a report
TREND_MEASUREMENTS = 1000
#: pixels whose characteristic is plotted (those departing most from the model)
PLOTTED_PIXELS = 4
#: heat-map cells carry their value as text up to this many columns
LABELLED_COLS = 16

_ID_RE = re.compile(r"^[0-9A-Za-z_-]+$")
_DEG = "\u00b0"
_PALETTE = ("#1b6fb3", "#b3261e", "#1b7f3b", "#8a4fb3", "#b36b00", "#444444")

_EXTRA_CSS = """
header.recalibrate { background: var(--degraded); }
header.within { background: var(--ok); }
svg.heat text { font-family: system-ui, sans-serif; }
.heats { display: grid; grid-template-columns: repeat(auto-fit, minmax(320px, 1fr));
         gap: 12px; }
"""


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
    try:
        text = render_report(clean, past)
    except Exception as exc:  # a report of unexpected shape: still a page, saying so
        log.exception("measurement %s: HTML report not rendered", mid)
        text = _page(f"grassd measurement {mid}", "failed", f"measurement {mid}",
                     f"<p>The report could not be rendered: {esc(exc)}. Its JSON is "
                     f"{esc(path.name)}.</p>")
    atomic_write_text(path.with_suffix(".html"), text)
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


def _num(v: float | None) -> float | None:
    """``v`` as a finite float, None for anything else (missing, null, NaN; text or a bool in
    a report of another shape)."""
    if isinstance(v, bool) or not isinstance(v, int | float):
        return None
    f = float(v)
    return f if math.isfinite(f) else None


def _mean(values: Sequence[float | None], absolute: bool = False) -> float | None:
    nums = [x for x in (_num(v) for v in values) if x is not None]
    if not nums:
        return None
    return float(np.mean(np.abs(nums) if absolute else nums))


def _pixels(report: MeasurementReport) -> list[PixelReport]:
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
        px = _pixels(r)
        u = u if isinstance(u := r.get("uniformity", {}), Mapping) else {}
        out.append({
            "measurement": r.get("measurement"), "started_at": r.get("started_at"),
            "before_de00": _num(u.get("before")), "after_de00": _num(u.get("after")),
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


# -- HTML -------------------------------------------------------------------------------------


def _f(v: float | None, fmt: str, unit: str = "") -> str:
    x = _num(v)
    return "-" if x is None else f"{format(x, fmt)}{unit}"


def _dl(items: Sequence[tuple[str, str | int | None]]) -> str:
    return "<dl>" + "".join(f"<dt>{html.escape(k)}</dt><dd>{esc(v)}</dd>"
                            for k, v in items) + "</dl>"


def _page(title: str, cls: str, head: str, body: str) -> str:
    return ("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
            "<meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">"
            f"<title>{esc(title)}</title><style>{CSS}{_EXTRA_CSS}</style></head><body>"
            f'<header class="health {cls}"><h1>{esc(head)}</h1></header>{body}</body></html>\n')


def grid_shape(n: int, shape: Sequence[int] | None = None) -> tuple[int, int]:
    """(rows, cols) of ``n`` pixels: ``shape`` when it is two positive integers whose product
    is ``n``, else one row.

    >>> grid_shape(6, [2, 3]), grid_shape(6, [4, 4]), grid_shape(5)
    ((2, 3), (1, 6), (1, 5))
    """
    if (isinstance(shape, list | tuple) and len(shape) == 2
            and all(isinstance(s, int) and not isinstance(s, bool) and s > 0 for s in shape)
            and shape[0] * shape[1] == n):
        return int(shape[0]), int(shape[1])
    return 1, max(n, 1)


def _colour(v: float | None, centre: float, half: float) -> str:
    """Diverging blue (below ``centre``) - white - red (above) for ``v``; grey for None."""
    if v is None:
        return "#cccccc"
    t = max(-1.0, min(1.0, (v - centre) / half)) if half > 0 else 0.0
    lo, hi = np.array([33, 102, 172]), np.array([178, 24, 43])
    end = hi if t > 0 else lo
    rgb = np.round(255 + (end - 255) * abs(t)).astype(int)
    return "#{:02x}{:02x}{:02x}".format(*rgb)


def svg_heatmap(values: Sequence[float | None], rows: int, cols: int, label: str, centre: float,
                fmt: str) -> str:
    """An inline SVG grid of ``values`` (pixel ``i`` at row ``i // cols``, column
    ``i % cols``, row 0 on top), coloured blue below ``centre``, red above, white at it, the
    scale symmetric about ``centre``; each cell tells its pixel and value on hover."""
    vals = [_num(v) for v in values]
    dev = [abs(v - centre) for v in vals if v is not None]
    half = max(dev) if dev else 0.0
    cell = 30 if cols <= LABELLED_COLS else max(4, min(30, 960 // max(cols, 1)))
    pad_l, pad_t, pad_b = 30, 8, 30
    width, height = pad_l + cols * cell + 8, pad_t + rows * cell + pad_b
    parts = [f'<svg class="heat" xmlns="http://www.w3.org/2000/svg" viewBox="0 0 {width} '
             f'{height}" width="{width}" height="{height}" role="img" '
             f'aria-label="{html.escape(label)}">']
    for i, v in enumerate(vals[:rows * cols]):
        r, c = divmod(i, cols)
        x, y = pad_l + c * cell, pad_t + r * cell
        text = "-" if v is None else format(v, fmt)
        parts.append(f'<rect x="{x}" y="{y}" width="{cell}" height="{cell}" '
                     f'fill="{_colour(v, centre, half)}" stroke="#fff">'
                     f"<title>pixel {i}: {html.escape(text)}</title></rect>")
        if cols <= LABELLED_COLS:
            parts.append(f'<text x="{x + cell / 2}" y="{y + cell / 2 + 3.5}" '
                         f'text-anchor="middle" font-size="9" fill="#111">'
                         f"{html.escape(text)}</text>")
    for r in range(rows):
        parts.append(f'<text x="{pad_l - 4}" y="{pad_t + r * cell + cell / 2 + 4}" '
                     f'text-anchor="end" font-size="10" fill="#555">{r}</text>')
    scale = (f"{centre - half:{fmt}} (blue) \u2026 {centre:{fmt}} (white) \u2026 "
             f"{centre + half:{fmt}} (red)")
    parts.append(f'<text x="{pad_l}" y="{height - 10}" font-size="11" fill="#333">'
                 f"{html.escape(scale)}</text></svg>")
    return "".join(parts)


def svg_characteristic(lengths: Sequence[float | None],
                       curves: Sequence[tuple[int, Sequence[float | None], Sequence[float | None],
                                              Sequence[float | None]]],
                       width: int = 520, height: int = 300) -> str:
    """An inline SVG plot of OGCD (dE00) against length (mm) for a few pixels: for each
    ``(index, measured, predicted, fitted)`` the measured points, the model's prediction
    (dashed) and the fitted pixel (solid), one colour per pixel."""
    x = np.array([_num(v) if _num(v) is not None else np.nan for v in lengths], float)
    ys = [np.array([np.nan if _num(v) is None else _num(v) for v in s], float)
          for _, *series in curves for s in series]
    allv = np.concatenate([y[np.isfinite(y)] for y in ys] + [np.zeros(0)])
    pad_l, pad_r, pad_t, pad_b = 50, 10, 10, 52
    w, h = width - pad_l - pad_r, height - pad_t - pad_b
    parts = [f'<svg xmlns="http://www.w3.org/2000/svg" viewBox="0 0 {width} {height}" '
             f'width="{width}" height="{height}" role="img" '
             'aria-label="OGCD against length: measured, predicted, fitted">',
             f'<rect x="{pad_l}" y="{pad_t}" width="{w}" height="{h}" fill="#fff" '
             'stroke="#999"/>']
    fx = x[np.isfinite(x)]
    if fx.size == 0 or allv.size == 0:
        parts.append(f'<text x="{pad_l + w / 2}" y="{pad_t + h / 2}" text-anchor="middle" '
                     'font-size="14" fill="#777">no characteristic</text></svg>')
        return "".join(parts)
    x0, x1 = float(fx.min()), float(fx.max())
    x1 = x1 if x1 > x0 else x0 + 1.0
    lo, hi = min(0.0, float(allv.min())), float(allv.max())
    hi = hi if hi > lo else lo + 1.0

    def px(a: float) -> float:
        return pad_l + (a - x0) / (x1 - x0) * w

    def py(b: float) -> float:
        return pad_t + (hi - b) / (hi - lo) * h

    for frac in (0.0, 0.5, 1.0):
        yy, val = pad_t + frac * h, hi - frac * (hi - lo)
        parts.append(f'<line x1="{pad_l}" x2="{pad_l + w}" y1="{yy:.1f}" y2="{yy:.1f}" '
                     f'stroke="#e3e3e3"/><text x="{pad_l - 4}" y="{yy + 4:.1f}" '
                     f'text-anchor="end" font-size="11" fill="#333">{val:.3g}</text>')
    for xx, anchor in ((x0, "start"), (x1, "end")):
        parts.append(f'<text x="{px(xx):.1f}" y="{pad_t + h + 14}" text-anchor="{anchor}" '
                     f'font-size="11" fill="#333">{xx:.3g} mm</text>')
    legend = []
    for k, (idx, meas, pred, fit) in enumerate(curves):
        colour = _PALETTE[k % len(_PALETTE)]
        for series, dash in ((pred, ' stroke-dasharray="5,4"'), (fit, "")):
            y = np.array([np.nan if _num(v) is None else _num(v) for v in series], float)
            pts = " ".join(f"{px(a):.1f},{py(b):.1f}" for a, b in zip(x, y, strict=False)
                           if np.isfinite(a) and np.isfinite(b))
            if pts:
                parts.append(f'<polyline points="{pts}" fill="none" stroke="{colour}" '
                             f'stroke-width="1.6"{dash}/>')
        y = np.array([np.nan if _num(v) is None else _num(v) for v in meas], float)
        parts.extend(f'<circle cx="{px(a):.1f}" cy="{py(b):.1f}" r="3" fill="{colour}"/>'
                     for a, b in zip(x, y, strict=False) if np.isfinite(a) and np.isfinite(b))
        legend.append((colour, f"pixel {idx}"))
    lx = pad_l
    for colour, text in legend:
        parts.append(f'<circle cx="{lx + 5}" cy="{height - 22}" r="4" fill="{colour}"/>'
                     f'<text x="{lx + 12}" y="{height - 18}" font-size="11" fill="#333">'
                     f"{html.escape(text)}</text>")
        lx += 80
    parts.append(f'<text x="{pad_l}" y="{height - 4}" font-size="11" fill="#555">points: '
                 "measured; dashed: model predicted; solid: fitted pixel</text></svg>")
    return "".join(parts)


def _uniformity(r: MeasurementReport) -> str:
    u = r.get("uniformity")
    if not isinstance(u, Mapping):
        return "<p>No uniformity measured.</p>"
    bd = b if isinstance(b := u.get("before_detail"), Mapping) else None
    ad = a if isinstance(a := u.get("after_detail"), Mapping) else None
    verdict = v if isinstance(v := r.get("verdict", {}), Mapping) else {}

    def pair(d: Uniformity | None) -> str:
        p = None if d is None else d.get("worst_pair")
        return f" (pixels {p[0]} and {p[1]})" if isinstance(p, list) and len(p) == 2 else ""

    imp = _num(u.get("improvement"))
    items: list[tuple[str, str | int | None]] = [("level", u.get("level")),
             ("worst pixel pair before", f"{_f(u.get('before'), '.2f', ' dE00')}{pair(bd)}"),
             ("worst pixel pair after", f"{_f(u.get('after'), '.2f', ' dE00')}{pair(ad)}"),
             ("improvement", "-" if imp is None else f"{imp:.2f}\u00d7"),
             ("tolerance", _f(verdict.get("tolerance_de00"), "g", " dE00"))]
    levels = lv if isinstance(lv := u.get("levels"), list) else []

    def at(d: Uniformity | None, key: Literal["ogcd_spread_de00", "mean_ogcd_de00"], k: int
           ) -> float | None:
        s = None if d is None else d.get(key)
        return s[k] if isinstance(s, list) and k < len(s) else None

    rows = [[td(lv, "n"), td(_f(at(bd, "ogcd_spread_de00", k), ".3f"), "n"),
             td(_f(at(ad, "ogcd_spread_de00", k), ".3f"), "n"),
             td(_f(at(bd, "mean_ogcd_de00", k), ".3f"), "n"),
             td(_f(at(ad, "mean_ogcd_de00", k), ".3f"), "n")] for k, lv in enumerate(levels)]
    table = html_table(["level", "OGCD spread before (dE00)", "OGCD spread after (dE00)",
                    "mean OGCD before (dE00)", "mean OGCD after (dE00)"], rows) if rows else ""
    return _dl(items) + table


def _camera(r: MeasurementReport) -> str:
    cam = c if isinstance(c := r.get("camera", {}), Mapping) else {}
    pos = cam.get("position_m")
    pos_s = ("(" + ", ".join(_f(v, ".3f") for v in pos) + ") m") if isinstance(pos, list) \
        else "-"
    vp = v if isinstance(v := cam.get("viewpoint", {}), Mapping) else {}
    light = lt if isinstance(lt := r.get("light", {}), Mapping) else {}
    lux = [x for x in (_num(v) for v in lx) if x is not None] \
        if isinstance(lx := light.get("lux"), list) else []
    tables = tb if isinstance(tb := r.get("tables", {}), Mapping) else {}
    pushed = tables.get("pushed")
    items: list[tuple[str, str | int | None]] = [("camera", cam.get("url")), ("position", pos_s),
             ("pose residual (rms)", _f(cam.get("rms_deg"), ".3f", _DEG)),
             ("as a viewpoint", f"h {_f(vp.get('h_cm'), '.1f', ' cm')}, d "
                                f"{_f(vp.get('d_m'), '.2f', ' m')}, \u03b8 "
                                f"{_f(vp.get('theta_deg'), '.1f', _DEG)}"),
             ("panorama", light.get("hdri")),
             ("lux while photographed", f"{min(lux):.0f} \u2026 {max(lux):.0f} "
                                        f"({len(lux)} shots)" if lux else "-"),
             ("patterns", ", ".join(_f(v, ".2f") for v in r.get("patterns_mm") or [])
              + " mm" if isinstance(r.get("patterns_mm"), list) else "-"),
             ("tables", f"{tables.get('granularity', '-')} tables from "
                        f"{tables.get('nominal_source', '-')}; run {tables.get('run_id', '-')}: "
                        f"{tables.get('status', '-')}"),
             ("pushed", "-" if not isinstance(pushed, list) else
              f"{sum(1 for p in pushed if p is True)} of {len(pushed)} controller(s)"),
             ("seconds", ", ".join(f"{k} {_f(v, '.0f')}" for k, v in
                                   (r.get("seconds") or {}).items())
              if isinstance(r.get("seconds"), Mapping) else "-")]
    return _dl(items)


def _heatmaps(r: MeasurementReport) -> str:
    px = _pixels(r)
    if not px:
        return "<p>No pixels measured.</p>"
    rows, cols = grid_shape(len(px), r.get("shape"))
    by_index = sorted(px, key=lambda p: p.get("index") if isinstance(p.get("index"), int)
                      else 0)
    maps = [("length offset (mm)", [p.get("length_offset_mm") for p in by_index], 0.0, ".2f"),
            ("green gain", [p.get("green_gain") for p in by_index], 1.0, ".3f"),
            ("yellow gain", [p.get("yellow_gain") for p in by_index], 1.0, ".3f")]
    figs = "".join(
        f'<figure><div class="scroll">'
        f"{svg_heatmap(values, rows, cols, label, centre, fmt)}"
        f"</div><figcaption>{html.escape(label)}, {rows} \u00d7 {cols}</figcaption></figure>"
        for label, values, centre, fmt in maps)
    return f'<div class="heats">{figs}</div>'


def _pixel_table(r: MeasurementReport) -> str:
    rows = [[td(p.get("index"), "n"), td(_f(p.get("length_offset_mm"), "+.3f"), "n"),
             td(_f(p.get("green_gain"), ".4f"), "n"), td(_f(p.get("yellow_gain"), ".4f"), "n"),
             td(_f(p.get("rms_lab"), ".3f"), "n"), td(_f(p.get("rms_lab_model"), ".3f"), "n")]
            for p in _pixels(r)]
    if not rows:
        return "<p>No pixels measured.</p>"
    return html_table(["pixel", "length offset (mm)", "green gain", "yellow gain",
                   "rms fitted (CIELAB)", "rms model (CIELAB)"], rows)


def _characteristic(r: MeasurementReport) -> str:
    ch = r.get("characteristic")
    if not isinstance(ch, Mapping):
        return "<p>No characteristic measured.</p>"
    items = [("max error, model predicted", _f(ch.get("max_error_predicted_de00"), ".3f",
                                                " dE00")),
             ("max error, fitted pixel", _f(ch.get("max_error_fitted_de00"), ".3f", " dE00"))]
    meas, pred, fit = (s if isinstance(s, list) else []
                       for s in (ch.get("measured_ogcd"), ch.get("predicted_ogcd"),
                                 ch.get("fitted_ogcd")))
    n = min(len(meas), len(pred), len(fit))

    def err(i: int) -> float:
        d = [abs(a - b) for a, b in zip(map(_num, meas[i]), map(_num, pred[i]), strict=False)
             if a is not None and b is not None] if isinstance(meas[i], list) \
            and isinstance(pred[i], list) else []
        return max(d, default=-1.0)

    chosen = sorted(range(n), key=err, reverse=True)[:PLOTTED_PIXELS]
    curves = [(i, meas[i], pred[i], fit[i]) for i in sorted(chosen)
              if all(isinstance(s[i], list) for s in (meas, pred, fit))]
    plot = ""
    if curves and isinstance(lengths := ch.get("lengths_mm"), list):
        plot = (f'<figure><div class="scroll">{svg_characteristic(lengths, curves)}'
                "</div><figcaption>OGCD (dE00) against length: the pixels farthest from the "
                "model</figcaption></figure>")
    return _dl(items) + plot


def _trend_html(points: Sequence[TrendPoint], current: str | None) -> str:
    if not points:
        return "<p>No successful measurement yet.</p>"
    clock = Clock("UTC")
    t = np.array([np.nan if (e := epoch_of(p.get("started_at"))) is None else e
                  for p in points], float)

    def series(values: Sequence[float | None]) -> np.ndarray:
        return np.array([np.nan if (x := _num(v)) is None else x for v in values], float)

    ok = np.isfinite(t)
    figs = [("worst pixel pair after correction (dE00)", [p.get("after_de00") for p in points],
             "#1b7f3b"),
            ("worst pixel pair before correction (dE00)",
             [p.get("before_de00") for p in points], "#b3261e"),
            ("mean green gain", [p.get("green_gain") for p in points], "#1b6fb3"),
            ("mean yellow gain", [p.get("yellow_gain") for p in points], "#b36b00"),
            ("mean |length offset| (mm)", [p.get("abs_offset_mm") for p in points], "#8a4fb3")]
    plots = '<div class="trends">' + "".join(
        f"<figure>{svg_trend(t[ok], series(values)[ok], label, clock, colour)}"
        f"<figcaption>{html.escape(label)} (UTC)</figcaption></figure>"
        for label, values, colour in figs) + "</div>"
    rows = [[td(("\u25b6 " if p.get("measurement") == current else "")
                 + str(p.get("measurement"))), td(p.get("started_at"), "t"),
             td(p.get("verdict"), "ok" if p.get("verdict") == "within tolerance" else "bad"),
             td(_f(p.get("before_de00"), ".2f"), "n"), td(_f(p.get("after_de00"), ".2f"), "n"),
             td(_f(p.get("green_gain"), ".4f"), "n"), td(_f(p.get("yellow_gain"), ".4f"), "n"),
             td(_f(p.get("abs_offset_mm"), ".3f"), "n")] for p in reversed(points)]
    return plots + html_table(["measurement", "started", "verdict", "before (dE00)",
                           "after (dE00)", "green gain", "yellow gain", "|offset| (mm)"], rows)


def render_report(report: MeasurementReport, past: Sequence[MeasurementReport] = ()) -> str:
    """The measurement ``report``'s HTML page (module docstring); ``past``: the reports whose
    trend it shows (oldest first; those of :func:`load_reports`)."""
    mid = report.get("measurement")
    word = headline(report)
    cls = verdict_class(report)
    meta = (f'<p class="meta">trigger {esc(report.get("trigger"))} &middot; started '
            f'{esc(report.get("started_at"))} &middot; finished '
            f'{esc(report.get("finished_at"))} &middot; status {esc(report.get("status"))}'
            "</p>")
    if report.get("status") == "ok":
        verdict = v if isinstance(v := report.get("verdict", {}), Mapping) else {}
        reason = verdict.get("reason")
        lead = f'<p class="reason">{esc(reason)}</p>' if reason else ""
        sections = [("Uniformity", _uniformity(report)),
                    ("Camera, light and tables", _camera(report)),
                    ("Pixels on the display", _heatmaps(report)),
                    ("Pixels", _pixel_table(report)),
                    ("Characteristic: measured vs predicted", _characteristic(report))]
    elif report.get("status") == "refused":  # its photos were not evidence
        evidence = report.get("evidence")
        findings = (evidence.get("findings") if isinstance(evidence, Mapping) else None) or []
        lead = ('<p class="reason">The photos were not evidence of the display: nothing was '
                "pushed; the last tables stay active.</p><h2>Refused</h2>"
                + "".join(f'<p class="reason">{esc(f.get("kind"))}: {esc(f.get("detail"))}'
                          "</p>" for f in findings if isinstance(f, Mapping)))
        sections = [("Uniformity", _uniformity(report))] if "uniformity" in report else []
    else:
        lead = (f'<p class="reason">The measurement did not finish; the last tables stay '
                f"active.</p><h2>Error</h2><p class=\"reason\">{esc(report.get('error'))}</p>")
        sections = []
    sections.append(("Trend over the measurements", _trend_html(trend(past), mid)))
    body = meta + lead + "".join(f"<section><h2>{html.escape(t)}</h2>{s}</section>"
                                 for t, s in sections)
    return _page(f"grassd measurement {mid}: {word}", cls, f"measurement {mid}: {word}", body)
