"""The content's card on the status page: what the display shows (source, frame rates, drops,
latencies, bad packets, the colour map) and a picture of the display as its controllers last
reported it (:mod:`~grassd.daemon.content.display_picture`)."""

from __future__ import annotations

from grassd.daemon.content.display_picture import shown_figure
from grassd.daemon.content.shown import ShownDisplay
from grassd.daemon.content.status import ContentStatusJson
from grassd.daemon.core.monitoring.page_parts import Card, Clock, html_table, td

#: the card's title on the page
TITLE = "Content"


def content_card(c: ContentStatusJson, shown: ShownDisplay | None, clock: Clock) -> Card:
    """What the display shows (the content feature's status ``c``, its JSON form; see
    docs/content.md), with the picture of ``shown`` (the controllers' last reported
    positions) when there is one. Placed after the serial lines."""
    return Card(TITLE, _table(c) + shown_figure(shown, clock), after="Serial lines")


def _table(c: ContentStatusJson) -> str:
    def ms(v: float | None) -> str:
        return "-" if v is None else f"{v:.0f}"

    bad = sum(r.get("malformed", 0) + r.get("oversized", 0)
              for r in (c.get("receivers") or {}).values())
    out = c.get("output")
    rows = [[td(c["source"]), td(c.get("detail") or "-"),
             td(f"{c['frames_out_per_s']:.1f}", "n"), td(f"{c['frames_in_per_s']:.1f}", "n"),
             td(c["dropped"], "n"),
             td(f"{ms(c.get('latency_ms_median'))} / {ms(c.get('latency_ms_p99'))}", "n"),
             td("- / -" if out is None else
                f"{ms(out['latency_ms_median'])} / {ms(out['latency_ms_p99'])}", "n"),
             td(bad, "n"), td(c["map"])]]
    table = html_table(["source", "detail", "frames out /s", "in /s", "dropped",
                    "packet to frame (ms, median / p99)", "to last ACK (ms)", "bad packets",
                    "map"], rows)
    return table
