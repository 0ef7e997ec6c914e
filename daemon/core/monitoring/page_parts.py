"""The building blocks of the status page that its sections and the features' cards share:
escaped text, numbers, the site's clock, tables, and a :class:`Card` (a feature's section of
the page). Every text is HTML-escaped and each of its lines free of control characters
(:func:`~grassd.daemon.core.safe_text.one_line`)."""

from __future__ import annotations

import html
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import datetime
from zoneinfo import ZoneInfo

from grassd.daemon.core.safe_text import one_line

#: The style sheet of the status page and of the reports that look like it.
CSS = """
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


@dataclass(frozen=True)
class Card:
    """A feature's section of the status page: its ``title``, its ``body`` (HTML, every text
    in it escaped) and the title of the page's own section it follows (``after``)."""

    title: str
    body: str
    after: str


def esc(v: object) -> str:
    """``v`` (its ``str``: a text, a number, an error) as HTML text: escaped, every line
    without control characters ("-" for None)."""
    text = "-" if v is None else str(v)
    return html.escape("\n".join(one_line(line, None) for line in text.split("\n")))


def name_text(v: str | None) -> str:
    """A name (a bundle's, its id) as HTML text: one line, escaped, cut when very long."""
    return html.escape("-" if v is None else one_line(v))


def num(v: float | None, fmt: str) -> str:
    """``v`` formatted by ``fmt``, "-" for None."""
    return "-" if v is None else format(v, fmt)


class Clock:
    """Epoch seconds -> local time of the site."""

    def __init__(self, tz: str) -> None:
        self.tz = ZoneInfo(tz)

    def __call__(self, t: float | None) -> str:
        """``t`` (epoch s) as the site's local time, "-" for None."""
        if t is None:
            return "-"
        return datetime.fromtimestamp(t, self.tz).strftime("%Y-%m-%d %H:%M:%S")


def html_table(headers: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    """An HTML table of cells already escaped (each ``<td>`` markup given whole); every cell
    is labelled with its column (``data-label``, shown on a phone where rows become cards)."""
    head = "".join(f"<th>{html.escape(h)}</th>" for h in headers)
    labels = [f'<td data-label="{html.escape(h)}"' for h in headers]
    body = "".join("<tr>" + "".join(cell.replace("<td", label, 1) for cell, label
                                    in zip(r, labels, strict=True)) + "</tr>" for r in rows)
    return f'<div class="scroll"><table><thead><tr>{head}</tr></thead><tbody>{body}</tbody>' \
           f"</table></div>"


def td(v: object, cls: str = "") -> str:
    """One table cell of ``v`` as text (:func:`esc`), of CSS class ``cls``."""
    return f'<td class="{cls}">{esc(v)}</td>' if cls else f"<td>{esc(v)}</td>"
