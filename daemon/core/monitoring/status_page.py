"""The status page: one static, self-contained ``reports/index.html`` for the operator.

Regenerated atomically after every run (and when the health or a controller's state changes)
by the daemon; no server: any web server, or a file browser, shows it. It holds the health
with its reasons, the active table with its plot (the run's PNG embedded as a data URI), the
every controller's state, the serial lines, the features' cards (each feature's own, e.g. the
display's last measurement and the content it shows: :class:`~grassd.daemon.core.monitoring
.page_parts.Card`), the last runs, trends over the kept history
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
from collections.abc import Mapping, Sequence
from datetime import datetime
from pathlib import Path
from typing import Any

import numpy as np

from grassd import __version__
from grassd.daemon.core.monitoring.line_report import describe_line, line_verdict
from grassd.daemon.core.monitoring.metrics import run_r2
from grassd.daemon.core.monitoring.page_parts import (
    CSS,
    Card,
    Clock,
    esc,
    html_table,
    name_text,
    num,
    td,
)
from grassd.daemon.core.monitoring.status_types import ControllerStatus, Status
from grassd.daemon.core.safe_text import one_line
from grassd.daemon.core.store.atomic import atomic_write_text
from grassd.daemon.core.store.history import History, RunRecord
from grassd.daemon.core.store.outcomes import refused

#: runs shown in "last runs" and kept runs plotted in the trends (newest)
LAST_RUNS = 15
TREND_RUNS = 2000
#: a trend's value axis spans at least this fraction of its largest value
MIN_SPAN = 0.02



def _name_td(v: str | None) -> str:
    return f"<td>{name_text(v)}</td>"


def _tick(v: float) -> str:
    """A value-axis label: whole numbers from 100 up, else four significant digits."""
    return f"{v:.0f}" if abs(v) >= 100 else f"{v:.4g}"


def svg_trend(times_s: np.ndarray, values: np.ndarray, label: str, clock: Clock,
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


def _active_table(cur: RunRecord | None, clock: Clock) -> str:
    if cur is None:
        return "<p>No table yet: the first successful run makes one.</p>"
    m = cur.metrics
    items = [("table", f"{cur.table_id} (crc {cur.table_crc:#010x})"),
             ("made by run", f"{cur.id} ({cur.trigger}) at {clock(cur.finished_at)}"),
             ("light captured", clock(cur.light_at)),
             ("lux", f"{num(cur.lux, '.0f')} ({cur.lux_source or '-'})"),
             ("R\u00b2 (OGCD vs level)", num(run_r2(m), ".5f")),
             ("max deviation", f"{num(m.get('max_dev_de00'), '.3f')} dE00"),
             ("OGCD range", f"{num(m.get('ogcd_range_de00'), '.2f')} dE00")]
    if m.get("granularity"):
        items.append(("tables", f"{m.get('tables')} {m['granularity']} table(s)"))
    dl = "".join(f"<dt>{html.escape(k)}</dt><dd>{esc(v)}</dd>" for k, v in items)
    return f"<dl>{dl}</dl>{_embedded_png(cur.plot_path)}"


def _controllers(controllers: Sequence[ControllerStatus],
                 push_failures: Mapping[str, int], clock: Clock) -> str:
    rows = []
    for c in controllers:
        rows.append([_name_td(c.name), td(c.state, "ok" if c.in_sync else "bad"),
                     td(c.table_id, "n"), td(clock(c.last_seen), "t"),
                     td(push_failures.get(c.name, 0), "n"),
                     f'<td class="reason">{esc(None if c.in_sync else c.error)}</td>'])
    return html_table(["controller", "state", "table", "last seen", "push failures", "error"], rows)


def _lines(lines: Mapping[str, Mapping[str, Any]]) -> str:
    """The serial lines the daemon has used: verdict, recent unanswered share, TABLE_CHUNK
    size reached (:mod:`grassd.daemon.core.monitoring.line_report`)."""
    if not lines:
        return "<p>None used yet.</p>"
    rows = []
    for port, q in lines.items():
        verdict = line_verdict(q)
        rate = q.get("recent_failure_rate")
        rows.append([td(port), td(verdict, {"good": "ok", "noisy": "", "failing": "bad"}
                                    .get(verdict, "")),
                     td(None if rate is None else f"{100 * rate:.1f}", "n"),
                     td(f"{q['chunk_bytes']} of {q['max_chunk_bytes']}", "n"),
                     f'<td class="reason">{esc(describe_line(port, q))}</td>'])
    return html_table(["port", "line", "unanswered (%)", "chunk (bytes)", "detail"], rows)


def _runs(runs: Sequence[RunRecord], clock: Clock) -> str:
    rows = []
    for r in runs:
        cls = "ok" if r.status == "ok" else ("bad" if r.status == "failed" else "")
        rows.append([td(r.id, "n"), td(clock(r.started_at), "t"), td(r.trigger),
                     td(r.status, cls),
                     td(None if r.lux is None else f"{r.lux:.0f} ({r.lux_source})", "n"),
                     td(num(run_r2(r.metrics), ".5f"), "n"),
                     td(num(r.metrics.get("max_dev_de00"), ".3f"), "n"),
                     td(None if r.finished_at is None
                         else f"{r.finished_at - r.started_at:.1f}", "n"),
                     f'<td class="reason">{esc(r.error)}</td>'])
    return html_table(["run", "started", "trigger", "status", "lux", "R\u00b2", "max dev (dE00)",
                   "seconds", "error"], rows)


def _trends(history: History, clock: Clock) -> str:
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


def _refused(history: History, clock: Clock) -> str:
    rows = [[td(o, "bad" if o == "quarantined" else ""), _name_td(e.name),
             _name_td(e.bundle_id),
             td(clock(e.updated_at), "t"), td(e.attempts, "n"),
             f'<td class="reason">{esc(e.reason)}</td>'] for o, e in refused(history)]
    if not rows:
        return "<p>None.</p>"
    return html_table(["outcome", "bundle", "id", "when", "attempts", "reason"], rows)


def render(status: Status, history: History, *, timezone: str,
           push_failures: Mapping[str, int] | None = None, now: float | None = None,
           cards: Sequence[Card] = ()) -> str:
    """The page (HTML text) for daemon ``status`` (with its health) and ``history``; times
    shown in the site's ``timezone`` (IANA name); ``now`` epoch s (the page's time);
    ``cards``: the features' sections (:class:`~grassd.daemon.core.monitoring.page_parts.Card`),
    each after the page's own section it names, in the order given."""
    clock = Clock(timezone)
    health = status.health
    live = status.daemon
    now = datetime.now().timestamp() if now is None else now
    reasons = "".join(f"<li>{html.escape(one_line(r, None))}</li>"  # one line each
                      for r in health.reasons)
    inbox = {} if live is None else live.inbox
    queue = ", ".join(f"{k} {v}" for k, v in inbox.items()) or "-"
    own = [
        ("Active table", _active_table(history.current_table(), clock)),
        ("Controllers", _controllers(status.controllers, push_failures or {}, clock)),
        ("Serial lines", _lines({} if live is None else live.lines)),
        ("Last runs", _runs(history.runs(LAST_RUNS), clock)),
        ("Trends", _trends(history, clock)),
        ("Rejected and quarantined bundles", _refused(history, clock)),
    ]
    titles = [t for t, _ in own]
    sections = []
    for title, body in own:
        sections.append((title, body))
        sections += [(c.title, c.body) for c in cards if c.after == title]
    sections += [(c.title, c.body) for c in cards if c.after not in titles]
    body = "".join(f"<section><h2>{html.escape(t)}</h2>{s}</section>" for t, s in sections)
    return (
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
        "<meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">"
        "<meta http-equiv=\"refresh\" content=\"60\">"
        f"<title>grassd: {html.escape(health.level)}</title><style>{CSS}</style></head><body>"
        f'<header class="health {health.level}"><h1>grassd: {html.escape(health.level)}</h1>'
        f"{f'<ul>{reasons}</ul>' if reasons else ''}</header>"
        f'<p class="meta">bundles: {esc(queue)}'
        f" &middot; page written {esc(clock(now))} ({html.escape(timezone)}) &middot; grassd "
        f"{html.escape(__version__)} &middot; state {esc(status.state_dir)}</p>"
        f"{body}</body></html>\n")


def write_page(path: str | os.PathLike[str], text: str) -> Path:
    """Write the page ``text`` to ``path`` atomically."""
    return atomic_write_text(path, text)
