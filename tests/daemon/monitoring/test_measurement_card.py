"""The status page's "Display measurement" card: the last measurement's verdict, uniformity
before -> after, when, a link to its HTML report that resolves from reports/index.html, and the
last trend points; "never measured" without one; a failed measurement's error escaped."""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path
from urllib.parse import unquote

from measurement_samples import failed_report, ok_report
from status_samples import status

from grassd.daemon.core.monitoring.page_parts import Clock
from grassd.daemon.core.monitoring.status_page import render
from grassd.daemon.core.store.history import History
from grassd.daemon.core.store.layout import StateLayout
from grassd.daemon.measure.card import CARD_TREND, measurement_card
from grassd.daemon.measure.report import write_report


def _card(page: str) -> str:
    m = re.search(r"<h2>Display measurement</h2>(.*?)</section>", page, re.S)
    assert m, "no measurement card"
    return m.group(1)


def _page(state: Path) -> str:
    h = History(state / "state.db")
    try:
        return render(dataclasses.replace(status(), state_dir=str(state)), h, timezone="UTC",
                      cards=[measurement_card(state, Clock("UTC"))])
    finally:
        h.close()


def test_card_says_never_measured(tmp_path):
    card = _card(_page(tmp_path / "state"))
    assert "Never measured" in card and "<a " not in card


def test_card_shows_the_last_measurement_and_its_trend(tmp_path):
    state = tmp_path / "state"
    layout = StateLayout(state)
    months = [(f"2026{m:02d}15T120000Z", 1.0 - 0.01 * m) for m in range(1, 8)]
    for mid, g in months:
        write_report(layout, ok_report(mid, green=g, after=0.5 + 0.1 * int(mid[4:6])))
    card = _card(_page(state))
    assert '<dd class="bad"><strong>recalibrate</strong></dd>' in card
    assert "3.10 dE00 \u2192 1.20 dE00 (2.6\u00d7 better)" in card
    assert "2026-07-15 12:00:00 (request)" in card
    [href] = re.findall(r'href="([^"]+)"', card)
    assert href == "../measure/20260715T120000Z.html"
    assert (layout.reports / unquote(href)).resolve() == \
        (layout.measure / "20260715T120000Z.html").resolve()
    rows = re.findall(r"<tr><td", card)
    assert len(rows) == CARD_TREND  # the newest points, newest first
    assert card.index("2026-07-15 12:00:00</td>") < card.index("2026-06-15 12:00:00</td>")
    assert "2026-02-15" not in card and ">0.9300<" in card


def test_card_shows_a_failed_measurement_escaped(tmp_path):
    state = tmp_path / "state"
    layout = StateLayout(state)
    write_report(layout, ok_report("20260101T000000Z"))
    write_report(layout, failed_report(error="no answer <script>alert(1)</script>\nat all"))
    (layout.measure / "20260301T000000Z.json").write_text("{not json")  # skipped, newest
    page = _page(state)
    card = _card(page)
    assert '<dd class="bad"><strong>failed</strong></dd>' in card
    assert "no answer &lt;script&gt;alert(1)&lt;/script&gt;\nat all" in card
    assert "<script" not in page
    assert ">within tolerance<" in card  # the earlier successful one, as a trend point
