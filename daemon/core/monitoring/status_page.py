"""The status page: one static, self-contained ``reports/index.html`` for the operator.

Regenerated atomically after every run (and when the health or a controller's state changes)
by the daemon; no server: any web server, or a file browser, shows it. It holds the health
with its reasons, the active table with its plot (the run's PNG embedded as a data URI), the
content the display shows with a picture of it as its controllers report it (GET_POSITIONS,
read while content plays: :mod:`~grassd.daemon.content.display_picture`), every
controller's state, the display's last measurement (``grassd measure``: its verdict,
uniformity before and after, a link to its HTML report and the last trend points, read from
``<state>/measure/*.json`` as the page is written), the last runs, trends over the kept history
(OGCD range, lux and R^2 against time, as inline SVG) and the rejected and quarantined bundles
with their reasons. No script, no external resource; the layout adapts to a phone's width (viewport
meta, tables scroll sideways, plots scale).

Every text on the page is HTML-escaped, and no line of it carries a control character
(:func:`~grassd.daemon.core.safe_text.one_line`): a bundle's name, chosen by whoever
writes the inbox, shows as one line with its newline as ``\\n``; a multi-line reason keeps its
lines.
"""

from __future__ import annotations

import base64
import html
import os
import urllib.parse
from collections.abc import Mapping, Sequence
from datetime import datetime
from pathlib import Path
from typing import Any
from zoneinfo import ZoneInfo

import numpy as np

from grassd import __version__
from grassd.daemon.content.display_picture import shown_figure
from grassd.daemon.content.shown import ShownDisplay
from grassd.daemon.core.monitoring.line_report import describe_line, line_verdict
from grassd.daemon.core.monitoring.metrics import run_r2
from grassd.daemon.core.monitoring.status_types import ControllerStatus, Status
from grassd.daemon.core.safe_text import one_line
from grassd.daemon.core.store.atomic import atomic_write_text
from grassd.daemon.core.store.history import History, RunRecord
from grassd.daemon.core.store.layout import StateLayout
from grassd.daemon.core.store.outcomes import refused

#: runs shown in "last runs" and kept runs plotted in the trends (newest)
LAST_RUNS = 15
TREND_RUNS = 2000
#: measurements read for the status page's card, and trend points it shows (newest)
CARD_MEASUREMENTS = 50
CARD_TREND = 5
#: a trend's value axis spans at least this fraction of its largest value
MIN_SPAN = 0.02

_CSS = """
:root { --ok: #1b7f3b; --degraded: #b36b00; --failed: #b3261e; }
* { box-sizing: border-box; }
body { font-family: system-ui, sans-serif; margin: 0 auto; max-width: 1100px; padding: 0 12px;
       color: #1d1d1d; background: #fafafa; line-height: 1.4; }
header.health { color: #fff; padding: 12px 16px; margin: 12px 0; border-radius: 6px; }
header.ok { background: var(--ok); } header.degraded { background: var(--degraded); }
header.failed { background: var(--failed); }
header h1 { margin: 0; font-size: 1.5em; } header ul { margin: 6px 0 0; padding-left: 20px; }
p.meta { color: #555; font-size: 0.85em; margin: 4px 0; }
h2 { font-size: 1.15em; margin: 1.4em 0 0.4em; border-bottom: 1px solid #ccc; }
.scroll { overflow-x: auto; -webkit-overflow-scrolling: touch; }
table { border-collapse: collapse; font-size: 0.9em; min-width: 100%; }
th, td { border: 1px solid #ccc; padding: 4px 8px; text-align: left; vertical-align: top; }
th { background: #eee; } td.n { text-align: right; font-variant-numeric: tabular-nums; }
td.t { white-space: nowrap; } td.ok { color: var(--ok); }
td.bad, dd.bad { color: var(--failed); font-weight: 600; } dd.ok { color: var(--ok); }
dl { display: grid; grid-template-columns: max-content 1fr; gap: 2px 12px; margin: 0; }
dt { color: #555; } dd { margin: 0; }
img, svg { max-width: 100%; height: auto; display: block; }
.trends { display: grid; grid-template-columns: repeat(auto-fit, minmax(300px, 1fr));
          gap: 12px; }
figure { margin: 0; background: #fff; border: 1px solid #ddd; border-radius: 4px; padding: 6px; }
figcaption { font-size: 0.9em; color: #333; }
.reason { white-space: pre-wrap; word-break: break-word; }
header, p.meta, dd, figcaption { overflow-wrap: anywhere; }
.plot img { min-width: 640px; }
figure.shown { display: inline-block; margin-top: 8px; }
figure.shown img { image-rendering: pixelated; }
@media (max-width: 600px) {
  body { padding: 0 6px; }
  /* tables become one card per row, each cell labelled with its column */
  table, tbody, tr, td { display: block; min-width: 0; } thead { display: none; }
  tr { border: 1px solid #ccc; border-radius: 4px; margin: 0 0 8px; background: #fff; }
  td { border: 0; border-bottom: 1px solid #eee; text-align: left; overflow-wrap: anywhere; }
  td.n { text-align: left; }
  td::before { content: attr(data-label); display: inline-block; min-width: 9.5em;
               color: #555; font-weight: 600; }
}
"""


def _esc(v: Any) -> str:
    """``v`` as HTML text: escaped, every line without control characters ("-" for None)."""
    text = "-" if v is None else str(v)
    return html.escape("\n".join(one_line(line, None) for line in text.split("\n")))


def _name(v: Any) -> str:
    """A name (a bundle's, its id) as HTML text: one line, escaped, cut when very long."""
    return html.escape("-" if v is None else one_line(v))


def _num(v: float | None, fmt: str) -> str:
    return "-" if v is None else format(v, fmt)


class _Clock:
    """Epoch seconds -> local time of the site."""

    def __init__(self, tz: str) -> None:
        self.tz = ZoneInfo(tz)

    def __call__(self, t: float | None) -> str:
        if t is None:
            return "-"
        return datetime.fromtimestamp(t, self.tz).strftime("%Y-%m-%d %H:%M:%S")


def _table(headers: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    """An HTML table of cells already escaped (each ``<td>`` markup given whole); every cell
    is labelled with its column (``data-label``, shown on a phone where rows become cards)."""
    head = "".join(f"<th>{html.escape(h)}</th>" for h in headers)
    labels = [f'<td data-label="{html.escape(h)}"' for h in headers]
    body = "".join("<tr>" + "".join(cell.replace("<td", label, 1) for cell, label
                                    in zip(r, labels, strict=True)) + "</tr>" for r in rows)
    return f'<div class="scroll"><table><thead><tr>{head}</tr></thead><tbody>{body}</tbody>' \
           f"</table></div>"


def _td(v: Any, cls: str = "") -> str:
    return f'<td class="{cls}">{_esc(v)}</td>' if cls else f"<td>{_esc(v)}</td>"


def _name_td(v: Any) -> str:
    return f"<td>{_name(v)}</td>"


def _tick(v: float) -> str:
    """A value-axis label: whole numbers from 100 up, else four significant digits."""
    return f"{v:.0f}" if abs(v) >= 100 else f"{v:.4g}"


def svg_trend(times_s: np.ndarray, values: np.ndarray, label: str, clock: _Clock,
              colour: str = "#1b6fb3", width: int = 380, height: int = 190) -> str:
    """An inline SVG line plot of ``values`` against ``times_s`` (epoch seconds), with the
    value range and the first and last time as axis labels; "no data" when empty."""
    ok = np.isfinite(values)
    t, v = np.asarray(times_s, float)[ok], np.asarray(values, float)[ok]
    pad_l, pad_r, pad_t, pad_b = 56, 10, 10, 36
    w, h = width - pad_l - pad_r, height - pad_t - pad_b
    parts = [f'<svg xmlns="http://www.w3.org/2000/svg" viewBox="0 0 {width} {height}" '
             f'width="{width}" height="{height}" role="img" aria-label="{html.escape(label)}">',
             f'<rect x="{pad_l}" y="{pad_t}" width="{w}" height="{h}" fill="#fff" '
             'stroke="#999"/>']
    if t.size == 0:
        parts.append(f'<text x="{pad_l + w / 2}" y="{pad_t + h / 2}" text-anchor="middle" '
                     'font-size="14" fill="#777">no data yet</text></svg>')
        return "".join(parts)
    t0, t1 = float(t.min()), float(t.max())
    lo, hi = float(v.min()), float(v.max())
    min_span = max(MIN_SPAN * max(abs(lo), abs(hi)), 1e-9)
    if hi - lo < min_span:  # a flat series: a flat line in the middle, not magnified noise
        mid = (hi + lo) / 2
        lo, hi = mid - min_span / 2, mid + min_span / 2
    span_t = t1 - t0 if t1 > t0 else 1.0
    x = pad_l + (t - t0) / span_t * w if t1 > t0 else np.full(t.size, pad_l + w / 2)
    y = pad_t + (hi - v) / (hi - lo) * h
    for frac in (0.0, 0.5, 1.0):  # horizontal grid lines with their values
        yy = pad_t + frac * h
        val = hi - frac * (hi - lo)
        parts.append(f'<line x1="{pad_l}" x2="{pad_l + w}" y1="{yy:.1f}" y2="{yy:.1f}" '
                     'stroke="#e3e3e3"/>')
        parts.append(f'<text x="{pad_l - 4}" y="{yy + 4:.1f}" text-anchor="end" '
                     f'font-size="11" fill="#333">{_tick(val)}</text>')
    pts = " ".join(f"{a:.1f},{b:.1f}" for a, b in zip(x, y, strict=True))
    parts.append(f'<polyline points="{pts}" fill="none" stroke="{colour}" stroke-width="1.8"/>')
    if t.size <= 200:
        parts.extend(f'<circle cx="{a:.1f}" cy="{b:.1f}" r="2.6" fill="{colour}"/>'
                     for a, b in zip(x, y, strict=True))
    for tt, anchor, xx in ((t0, "start", pad_l), (t1, "end", pad_l + w)):
        parts.append(f'<text x="{xx}" y="{height - 20}" text-anchor="{anchor}" font-size="11" '
                     f'fill="#333">{html.escape(clock(tt))}</text>')
    parts.append(f'<text x="{pad_l + w / 2}" y="{height - 4}" text-anchor="middle" '
                 f'font-size="11" fill="#555">{t.size} run(s)</text></svg>')
    return "".join(parts)


def _embedded_png(path: str | None) -> str:
    if not path:
        return '<p class="meta">no plot kept for this run</p>'
    try:
        data = Path(path).read_bytes()
    except OSError as exc:
        return f'<p class="meta">plot {html.escape(path)} unreadable: ' \
               f"{html.escape(exc.strerror or str(exc))}</p>"
    uri = base64.b64encode(data).decode("ascii")
    return (f'<div class="scroll plot"><img src="data:image/png;base64,{uri}" '
            'alt="characteristic and table of the active run"></div>')


def _active_table(cur: RunRecord | None, clock: _Clock) -> str:
    if cur is None:
        return "<p>No table yet: the first successful run makes one.</p>"
    m = cur.metrics
    items = [("table", f"{cur.table_id} (crc {cur.table_crc:#010x})"),
             ("made by run", f"{cur.id} ({cur.trigger}) at {clock(cur.finished_at)}"),
             ("light captured", clock(cur.light_at)),
             ("lux", f"{_num(cur.lux, '.0f')} ({cur.lux_source or '-'})"),
             ("R\u00b2 (OGCD vs level)", _num(run_r2(m), ".5f")),
             ("max deviation", f"{_num(m.get('max_dev_de00'), '.3f')} dE00"),
             ("OGCD range", f"{_num(m.get('ogcd_range_de00'), '.2f')} dE00")]
    if m.get("granularity"):
        items.append(("tables", f"{m.get('tables')} {m['granularity']} table(s)"))
    dl = "".join(f"<dt>{html.escape(k)}</dt><dd>{_esc(v)}</dd>" for k, v in items)
    return f"<dl>{dl}</dl>{_embedded_png(cur.plot_path)}"


def _controllers(controllers: Sequence[ControllerStatus],
                 push_failures: Mapping[str, int], clock: _Clock) -> str:
    rows = []
    for c in controllers:
        rows.append([_name_td(c.name), _td(c.state, "ok" if c.in_sync else "bad"),
                     _td(c.table_id, "n"), _td(clock(c.last_seen), "t"),
                     _td(push_failures.get(c.name, 0), "n"),
                     f'<td class="reason">{_esc(None if c.in_sync else c.error)}</td>'])
    return _table(["controller", "state", "table", "last seen", "push failures", "error"], rows)


def _lines(lines: Mapping[str, Mapping[str, Any]]) -> str:
    """The serial lines the daemon has used: verdict, recent unanswered share, TABLE_CHUNK
    size reached (:mod:`grassd.daemon.core.monitoring.line_report`)."""
    if not lines:
        return "<p>None used yet.</p>"
    rows = []
    for port, q in lines.items():
        verdict = line_verdict(q)
        rate = q.get("recent_failure_rate")
        rows.append([_td(port), _td(verdict, {"good": "ok", "noisy": "", "failing": "bad"}
                                    .get(verdict, "")),
                     _td(None if rate is None else f"{100 * rate:.1f}", "n"),
                     _td(f"{q['chunk_bytes']} of {q['max_chunk_bytes']}", "n"),
                     f'<td class="reason">{_esc(describe_line(port, q))}</td>'])
    return _table(["port", "line", "unanswered (%)", "chunk (bytes)", "detail"], rows)


def _content(c: Mapping[str, Any], shown: ShownDisplay | None = None,
             clock: _Clock | None = None) -> str:
    """What the display shows (the content feature's status, docs/content.md), with the
    picture of ``shown`` (the controllers' last reported positions) when there is one."""
    def ms(v: float | None) -> str:
        return "-" if v is None else f"{v:.0f}"

    bad = sum(r.get("malformed", 0) + r.get("oversized", 0)
              for r in (c.get("receivers") or {}).values())
    out = c.get("output") or {}
    rows = [[_td(c["source"]), _td(c.get("detail") or "-"),
             _td(f"{c['frames_out_per_s']:.1f}", "n"), _td(f"{c['frames_in_per_s']:.1f}", "n"),
             _td(c["dropped"], "n"),
             _td(f"{ms(c.get('latency_ms_median'))} / {ms(c.get('latency_ms_p99'))}", "n"),
             _td(f"{ms(out.get('latency_ms_median'))} / {ms(out.get('latency_ms_p99'))}", "n"),
             _td(bad, "n"), _td(c["map"])]]
    table = _table(["source", "detail", "frames out /s", "in /s", "dropped",
                    "packet to frame (ms, median / p99)", "to last ACK (ms)", "bad packets",
                    "map"], rows)
    return table + ("" if clock is None else shown_figure(shown, clock))


def _runs(runs: Sequence[RunRecord], clock: _Clock) -> str:
    rows = []
    for r in runs:
        cls = "ok" if r.status == "ok" else ("bad" if r.status == "failed" else "")
        rows.append([_td(r.id, "n"), _td(clock(r.started_at), "t"), _td(r.trigger),
                     _td(r.status, cls),
                     _td(None if r.lux is None else f"{r.lux:.0f} ({r.lux_source})", "n"),
                     _td(_num(run_r2(r.metrics), ".5f"), "n"),
                     _td(_num(r.metrics.get("max_dev_de00"), ".3f"), "n"),
                     _td(None if r.finished_at is None
                         else f"{r.finished_at - r.started_at:.1f}", "n"),
                     f'<td class="reason">{_esc(r.error)}</td>'])
    return _table(["run", "started", "trigger", "status", "lux", "R\u00b2", "max dev (dE00)",
                   "seconds", "error"], rows)


def _trends(history: History, clock: _Clock) -> str:
    ok = [r for r in history.runs(TREND_RUNS) if r.status == "ok" and r.finished_at]
    ok.reverse()
    t = np.array([r.finished_at for r in ok], float)

    def series(f) -> np.ndarray:
        return np.array([np.nan if (x := f(r)) is None else float(x) for r in ok], float)

    figs = [("OGCD range (dE00)", series(lambda r: r.metrics.get("ogcd_range_de00")),
             "#1b7f3b"),
            ("ambient illuminance (lux)", series(lambda r: r.lux), "#b36b00"),
            ("R\u00b2 of OGCD vs level", series(lambda r: run_r2(r.metrics)), "#1b6fb3")]
    return '<div class="trends">' + "".join(
        f"<figure>{svg_trend(t, v, label, clock, colour)}<figcaption>{html.escape(label)}"
        "</figcaption></figure>" for label, v, colour in figs) + "</div>"


def _measurement(state_dir: str, clock: _Clock) -> str:
    """The display's last measurement (``grassd measure``) from the JSON reports in
    ``<state_dir>/measure``: verdict, uniformity before -> after (dE00), when, a link to its HTML
    report (relative: the page is ``<state_dir>/reports/index.html``) and the last trend points;
    "never measured" when there is none."""
    from grassd.daemon.measure.report import epoch_of, headline, load_reports, trend

    try:
        reports = load_reports(StateLayout(state_dir), CARD_MEASUREMENTS)
    except OSError as exc:
        return f"<p>Measurements unreadable: {_esc(exc)}</p>"
    if not reports:
        return ("<p>Never measured: <code>grassd measure</code> photographs the display under "
                "test patterns and corrects each pixel's departure from the model.</p>")
    last = reports[-1]
    word = headline(last)
    cls = {"within tolerance": "ok"}.get(word, "bad")
    u = last.get("uniformity") if isinstance(last.get("uniformity"), Mapping) else {}

    def de(v: Any) -> str:
        return f"{v:.2f} dE00" if isinstance(v, int | float) and not isinstance(v, bool) \
            else "-"

    imp = u.get("improvement")
    uni = f"{de(u.get('before'))} \u2192 {de(u.get('after'))}" + (
        f" ({imp:.1f}\u00d7 better)" if isinstance(imp, int | float) and imp > 0 else "")
    verdict = last.get("verdict") if isinstance(last.get("verdict"), Mapping) else {}
    detail = verdict.get("reason") if last.get("status") == "ok" else last.get("error")
    page = Path(str(last.get("report", ""))).with_suffix(".html")
    link = (f'<a href="../measure/{html.escape(urllib.parse.quote(page.name))}">'
            f"{_name(page.name)}</a>" if page.name and page.is_file() else "-")
    items = [f'<dt>verdict</dt><dd class="{cls}"><strong>{_esc(word)}</strong></dd>',
             f'<dt>why</dt><dd class="reason">{_esc(detail)}</dd>',
             f"<dt>uniformity (worst pixel pair)</dt><dd>{_esc(uni)}</dd>",
             f"<dt>when</dt><dd>{_esc(clock(epoch_of(last.get('started_at'))))} "
             f"({_esc(last.get('trigger'))})</dd>",
             f"<dt>report</dt><dd>{link}</dd>"]
    points = trend(reports)[-CARD_TREND:]
    rows = [[_td(clock(epoch_of(p["started_at"])), "t"),
             _td(p["verdict"], "ok" if p["verdict"] == "within tolerance" else "bad"),
             _td(_num(p["before_de00"], ".2f"), "n"), _td(_num(p["after_de00"], ".2f"), "n"),
             _td(_num(p["green_gain"], ".4f"), "n"), _td(_num(p["yellow_gain"], ".4f"), "n"),
             _td(_num(p["abs_offset_mm"], ".3f"), "n")] for p in reversed(points)]
    table = _table(["measured", "verdict", "before (dE00)", "after (dE00)", "green gain",
                    "yellow gain", "|offset| (mm)"], rows) if rows else ""
    return f"<dl>{''.join(items)}</dl>{table}"


def _refused(history: History, clock: _Clock) -> str:
    rows = [[_td(o, "bad" if o == "quarantined" else ""), _name_td(e.name),
             _name_td(e.bundle_id),
             _td(clock(e.updated_at), "t"), _td(e.attempts, "n"),
             f'<td class="reason">{_esc(e.reason)}</td>'] for o, e in refused(history)]
    if not rows:
        return "<p>None.</p>"
    return _table(["outcome", "bundle", "id", "when", "attempts", "reason"], rows)


def render(status: Status, history: History, *, timezone: str,
           push_failures: Mapping[str, int] | None = None, now: float | None = None,
           shown: ShownDisplay | None = None) -> str:
    """The page (HTML text) for daemon ``status`` (with its health) and ``history``; times
    shown in the site's ``timezone`` (IANA name); ``now`` epoch s (the page's time);
    ``shown``: the display as its controllers last reported it (a picture under Content)."""
    clock = _Clock(timezone)
    health = status.health
    live = status.daemon
    now = datetime.now().timestamp() if now is None else now
    reasons = "".join(f"<li>{html.escape(one_line(r, None))}</li>"  # one line each
                      for r in health.reasons)
    inbox = {} if live is None else live.inbox
    queue = ", ".join(f"{k} {v}" for k, v in inbox.items()) or "-"
    sections = [
        ("Active table", _active_table(history.current_table(), clock)),
        ("Display measurement", _measurement(status.state_dir, clock)),
        ("Controllers", _controllers(status.controllers, push_failures or {}, clock)),
        ("Serial lines", _lines({} if live is None else live.lines)),
        *([("Content", _content(live.content, shown, clock))]
          if live is not None and live.content else []),
        ("Last runs", _runs(history.runs(LAST_RUNS), clock)),
        ("Trends", _trends(history, clock)),
        ("Rejected and quarantined bundles", _refused(history, clock)),
    ]
    body = "".join(f"<section><h2>{html.escape(t)}</h2>{s}</section>" for t, s in sections)
    return (
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
        "<meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">"
        "<meta http-equiv=\"refresh\" content=\"60\">"
        f"<title>grassd: {html.escape(health.level)}</title><style>{_CSS}</style></head><body>"
        f'<header class="health {health.level}"><h1>grassd: {html.escape(health.level)}</h1>'
        f"{f'<ul>{reasons}</ul>' if reasons else ''}</header>"
        f'<p class="meta">bundles: {_esc(queue)}'
        f" &middot; page written {_esc(clock(now))} ({html.escape(timezone)}) &middot; grassd "
        f"{html.escape(__version__)} &middot; state {_esc(status.state_dir)}</p>"
        f"{body}</body></html>\n")


def write_page(path: str | os.PathLike[str], text: str) -> Path:
    """Write the page ``text`` to ``path`` atomically."""
    return atomic_write_text(path, text)
