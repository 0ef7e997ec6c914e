"""The display measurement's card on the status page: the last measurement's verdict,
uniformity before and after, when, a link to its HTML report and the last trend points, read
from ``<state>/measure/*.json`` as the page is written."""

from __future__ import annotations

import html
import urllib.parse
from collections.abc import Mapping
from pathlib import Path

from grassd.daemon.core.monitoring.page_parts import (
    Card,
    Clock,
    esc,
    html_table,
    name_text,
    num,
    td,
)
from grassd.daemon.core.store.layout import StateLayout
from grassd.daemon.measure.report import epoch_of, headline, load_reports, trend

#: the card's title on the page
TITLE = "Display measurement"
#: measurements read for the card, and trend points it shows (newest)
CARD_MEASUREMENTS = 50
CARD_TREND = 5


def measurement_card(state_dir: str | Path, clock: Clock) -> Card:
    """The display's last measurement (``grassd measure``) from the JSON reports in
    ``<state_dir>/measure``: verdict, uniformity before -> after (dE00), when, a link to its HTML
    report (relative: the page is ``<state_dir>/reports/index.html``) and the last trend points;
    "never measured" when there is none. Placed after the active table."""
    return Card(TITLE, _body(state_dir, clock), after="Active table")


def _body(state_dir: str | Path, clock: Clock) -> str:
    try:
        reports = load_reports(StateLayout(state_dir), CARD_MEASUREMENTS)
    except OSError as exc:
        return f"<p>Measurements unreadable: {esc(exc)}</p>"
    if not reports:
        return ("<p>Never measured: <code>grassd measure</code> photographs the display under "
                "test patterns and corrects each pixel's departure from the model.</p>")
    last = reports[-1]
    word = headline(last)
    cls = {"within tolerance": "ok"}.get(word, "bad")
    u = u if isinstance(u := last.get("uniformity", {}), Mapping) else {}

    def de(v: float | None) -> str:
        return f"{v:.2f} dE00" if isinstance(v, int | float) and not isinstance(v, bool) \
            else "-"

    imp = u.get("improvement")
    uni = f"{de(u.get('before'))} \u2192 {de(u.get('after'))}" + (
        f" ({imp:.1f}\u00d7 better)" if isinstance(imp, int | float) and imp > 0 else "")
    verdict = v if isinstance(v := last.get("verdict", {}), Mapping) else {}
    detail = verdict.get("reason") if last.get("status") == "ok" else last.get("error")
    page = Path(str(last.get("report", ""))).with_suffix(".html")
    link = (f'<a href="../measure/{html.escape(urllib.parse.quote(page.name))}">'
            f"{name_text(page.name)}</a>" if page.name and page.is_file() else "-")
    items = [f'<dt>verdict</dt><dd class="{cls}"><strong>{esc(word)}</strong></dd>',
             f'<dt>why</dt><dd class="reason">{esc(detail)}</dd>',
             f"<dt>uniformity (worst pixel pair)</dt><dd>{esc(uni)}</dd>",
             f"<dt>when</dt><dd>{esc(clock(epoch_of(last.get('started_at'))))} "
             f"({esc(last.get('trigger'))})</dd>",
             f"<dt>report</dt><dd>{link}</dd>"]
    points = trend(reports)[-CARD_TREND:]
    rows = [[td(clock(epoch_of(p["started_at"])), "t"),
             td(p["verdict"], "ok" if p["verdict"] == "within tolerance" else "bad"),
             td(num(p["before_de00"], ".2f"), "n"), td(num(p["after_de00"], ".2f"), "n"),
             td(num(p["green_gain"], ".4f"), "n"), td(num(p["yellow_gain"], ".4f"), "n"),
             td(num(p["abs_offset_mm"], ".3f"), "n")] for p in reversed(points)]
    table = html_table(["measured", "verdict", "before (dE00)", "after (dE00)", "green gain",
                    "yellow gain", "|offset| (mm)"], rows) if rows else ""
    return f"<dl>{''.join(items)}</dl>{table}"
