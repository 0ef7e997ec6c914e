"""A measurement report's HTML page (:mod:`grassd.daemon.measure.report` writes it beside
the JSON).

The HTML has no script and no external resource (styles inline, plots as inline SVG); every
text from the report is HTML-escaped and shown without control characters, as on the status
page (:mod:`grassd.daemon.core.monitoring.status_page`, whose style and helpers it shares). It
shows: the verdict with its reason (or the error of a failed measurement), the uniformity
before and after the correction (worst pixel pair at the mid level, improvement, OGCD spread
per level), the camera's pose, heat maps of every pixel's length offset and gains laid out as
the display (rows x cols), the per-pixel table, measured vs predicted vs fitted OGCD, and the
trend over the past measurements.
"""

from __future__ import annotations

import html
import logging
from collections.abc import Mapping, Sequence
from typing import Literal

import numpy as np

from grassd.daemon.core.monitoring.page_parts import CSS, Clock, esc, html_table, td
from grassd.daemon.core.monitoring.status_page import svg_trend
from grassd.daemon.measure.report import (
    MeasurementReport,
    TrendPoint,
    Uniformity,
    epoch_of,
    headline,
    trend,
    verdict_class,
)
from grassd.daemon.measure.report import finite_number as _num
from grassd.daemon.measure.report import pixels_of as _pixels

log = logging.getLogger(__name__)

#: pixels whose characteristic is plotted (those departing most from the model)
PLOTTED_PIXELS = 4
#: heat-map cells carry their value as text up to this many columns
LABELLED_COLS = 16

_DEG = "\u00b0"
_PALETTE = ("#1b6fb3", "#b3261e", "#1b7f3b", "#8a4fb3", "#b36b00", "#444444")

_EXTRA_CSS = """
header.recalibrate { background: var(--degraded); }
header.within { background: var(--ok); }
svg.heat text { font-family: system-ui, sans-serif; }
.heats { display: grid; grid-template-columns: repeat(auto-fit, minmax(320px, 1fr));
         gap: 12px; }
"""


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


def report_page(report: MeasurementReport, past: Sequence[MeasurementReport], json_name: str
                ) -> str:
    """The HTML page of ``report`` (:func:`render_report`); a report of a shape it cannot
    render still gets a page, which says so and names its JSON file ``json_name``."""
    mid = str(report.get("measurement", ""))
    try:
        return render_report(report, past)
    except Exception as exc:  # a report of unexpected shape: still a page, saying so
        log.exception("measurement %s: HTML report not rendered", mid)
        return _page(f"grassd measurement {mid}", "failed", f"measurement {mid}",
                     f"<p>The report could not be rendered: {esc(exc)}. Its JSON is "
                     f"{esc(json_name)}.</p>")
