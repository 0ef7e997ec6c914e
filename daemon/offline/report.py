"""Self-contained HTML reports with PNG plots for ``grassd validate`` and ``grassd experiment``.

Every plot is a matplotlib figure rendered to PNG and embedded as a ``data:image/png;base64``
URI, so a report is one file that opens anywhere (no network, no side files). Each ``<img>``
carries its PNG's pixel ``width``/``height`` and an ``alt`` text. Plots follow the paper:
real characteristic green, simulated orange (Figures 8-10), and the 8-bit calibration scatter
with least-squares lines and R^2 (Figure 11).
"""

from __future__ import annotations

import base64
import html
import io
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from grassd.calib.colour_spaces import lab_to_srgb
from grassd.daemon.offline.colour_chain import chain_text

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

    from grassd.daemon.offline.fit import FitResult, ViewpointFit
    from grassd.daemon.offline.validate import (
        CalibrationCheck,
        ValidationResult,
        ViewpointComparison,
    )

REAL_COLOUR = "#2e8b3a"
SIM_COLOUR = "#f08c1e"
_CSS = """
body { font-family: sans-serif; margin: 2em auto; max-width: 1100px; color: #222; }
h1 { font-size: 1.5em; } h2 { font-size: 1.2em; margin-top: 1.6em; }
table { border-collapse: collapse; margin: 0.6em 0; font-size: 0.9em; }
th, td { border: 1px solid #bbb; padding: 3px 8px; text-align: right; }
th { background: #eee; } td.l, th.l { text-align: left; }
img { display: block; margin: 0.6em 0; max-width: 100%; height: auto; }
p.note { color: #555; font-size: 0.9em; }
"""


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def figure_png(fig: Figure, dpi: int = 100) -> bytes:
    """PNG bytes of a matplotlib figure (then closed)."""
    plt = _plt()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    plt.close(fig)
    return buf.getvalue()


def png_size(png: bytes) -> tuple[int, int]:
    """(width, height) in pixels from a PNG's IHDR chunk."""
    if png[:8] != b"\x89PNG\r\n\x1a\n":
        raise ValueError("not a PNG")
    return int.from_bytes(png[16:20], "big"), int.from_bytes(png[20:24], "big")


def img_tag(png: bytes, alt: str) -> str:
    """``<img>`` with the PNG embedded as a base64 data URI and its pixel size."""
    w, h = png_size(png)
    data = base64.b64encode(png).decode("ascii")
    return (f'<img src="data:image/png;base64,{data}" width="{w}" height="{h}" '
            f'alt="{html.escape(alt)}">')


def table(headers: Sequence[str], rows: Sequence[Sequence[str | float]], left: int = 1) -> str:
    """An HTML table; the first ``left`` columns are left-aligned; floats shown as given."""
    def cell(tag: str, i: int, v: str | float) -> str:
        cls = ' class="l"' if i < left else ""
        return f"<{tag}{cls}>{html.escape(str(v))}</{tag}>"

    head = "".join(cell("th", i, h) for i, h in enumerate(headers))
    body = "".join("<tr>" + "".join(cell("td", i, v) for i, v in enumerate(r)) + "</tr>"
                   for r in rows)
    return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


def page(title: str, sections: Sequence[tuple[str, str]], intro: str = "") -> str:
    """A complete HTML document: title, optional intro paragraph, (heading, html) sections."""
    parts = [f"<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
             f"<title>{html.escape(title)}</title><style>{_CSS}</style></head><body>",
             f"<h1>{html.escape(title)}</h1>"]
    if intro:
        parts.append(f"<p>{intro}</p>")
    for heading, body in sections:
        parts.append(f"<section><h2>{html.escape(heading)}</h2>{body}</section>")
    parts.append("</body></html>\n")
    return "\n".join(parts)


def f2(v: float | None, digits: int = 2) -> str:
    """A number for a table (``-`` for None/NaN)."""
    if v is None or (isinstance(v, float) and not np.isfinite(v)):
        return "-"
    return f"{v:.{digits}f}"


# ----------------------------------------------------------------------------- plots
def _curve_axes(ax: Axes, vc: ViewpointComparison, title: str, small: bool = False) -> None:
    x = vc.real.lengths_mm
    ax.plot(x, vc.real.ogcd, "o-", color=REAL_COLOUR, ms=2.5 if small else 4, label="real")
    se = vc.sim.ogcd_stderr
    ax.errorbar(vc.sim.lengths_mm, vc.sim.ogcd, yerr=se, fmt="s-", color=SIM_COLOUR,
                ms=2.5 if small else 4, capsize=2, label="simulated")
    ax.set_title(title, fontsize=8 if small else 10)
    ax.text(0.03, 0.95, f"F {vc.frechet:.2f}\nmax {vc.max_error:.2f} @ "
            f"{vc.max_error_length_mm:.1f}", transform=ax.transAxes, va="top",
            fontsize=7 if small else 9)
    ax.grid(alpha=0.3)


def _panels(n: int, max_cols: int, size: tuple[float, float]) -> tuple[Figure, list[Axes]]:
    """A figure of ``n`` panels sharing their y axis, ``max_cols`` a row at most, each
    ``size`` inches; the first panel is labelled OGCD and the unused ones are hidden."""
    plt = _plt()
    cols = min(n, max_cols)
    rows = int(np.ceil(n / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(size[0] * cols, size[1] * rows),
                             squeeze=False, sharey=True)
    flat = list(axes.ravel())
    for ax in flat[n:]:
        ax.axis("off")
    flat[0].set_ylabel("OGCD [dE00]")
    return fig, flat[:n]


def curves_figure(viewpoints: Sequence[ViewpointComparison],
                  titles: Sequence[str] | None = None) -> Figure:
    """Real vs simulated OGCD vs length, one panel per comparison (up to 5 columns)."""
    fig, axes = _panels(len(viewpoints), 5, (3.2, 2.8))
    for k, (ax, vc) in enumerate(zip(axes, viewpoints, strict=True)):
        _curve_axes(ax, vc, titles[k] if titles else vc.label)
        ax.set_xlabel("green length [mm]")
    axes[0].legend(fontsize=8, loc="lower right")
    fig.tight_layout()
    return fig


def grid_figure(viewpoints: Sequence[ViewpointComparison]) -> Figure:
    """The paper's Figure 8: a grid of real vs simulated curves, rows = eye height h
    (highest first), columns = angle theta."""
    plt = _plt()
    hs = sorted({v.viewpoint[0] for v in viewpoints}, reverse=True)
    ts = sorted({v.viewpoint[2] for v in viewpoints})
    fig, axes = plt.subplots(len(hs), len(ts), figsize=(2.6 * len(ts), 2.2 * len(hs)),
                             squeeze=False, sharex=True, sharey=True)
    for ax in axes.ravel():
        ax.axis("off")
    for vc in viewpoints:
        ax = axes[hs.index(vc.viewpoint[0])][ts.index(vc.viewpoint[2])]
        ax.axis("on")
        _curve_axes(ax, vc, f"h {vc.viewpoint[0]:g} cm, theta {vc.viewpoint[2]:g} deg",
                    small=True)
    for ax in axes[-1]:
        ax.set_xlabel("length [mm]", fontsize=8)
    for row in axes:
        row[0].set_ylabel("OGCD", fontsize=8)
    handles, labels = next(ax for ax in axes.ravel() if ax.axison).get_legend_handles_labels()
    fig.tight_layout(rect=(0, 0, 1, 0.96))
    fig.legend(handles, labels, loc="upper center", ncol=2, fontsize=8, frameon=False)
    return fig


def calibration_figure(cal: CalibrationCheck) -> Figure:
    """The paper's Figure 11: real OGCD vs 8-bit level before calibration, with the table from
    the real characteristic, and with the table from the simulated one; red dotted lines are
    least-squares fits with their R^2."""
    plt = _plt()
    fig, axes = plt.subplots(1, 3, figsize=(11, 3.4), sharey=True)
    panels = [("uncalibrated (length linear in level)", cal.before, cal.r2_before),
              ("calibrated with the real characteristic", cal.after_real, cal.r2_after_real),
              ("calibrated with the simulated characteristic", cal.after_sim, cal.r2_after_sim)]
    x = cal.levels
    for ax, (title, y, r2) in zip(axes, panels, strict=True):
        ax.scatter(x[::3], y[::3], s=5, color=REAL_COLOUR)
        slope, icpt = np.polyfit(x, y, 1)
        ax.plot(x, icpt + slope * x, ":", color="red", lw=1.5)
        ax.set_title(title, fontsize=9)
        ax.text(0.05, 0.92, f"$R^2$ = {r2:.3f}", transform=ax.transAxes)
        ax.set_xlabel("8-bit level")
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("OGCD of the real pixel [dE00]")
    fig.tight_layout()
    return fig


def appearance_figure(vc: ViewpointComparison) -> Figure:
    """The paper's Figure 9 as colour swatches: the measured (top) and simulated (bottom) grass
    colour at each length, shown in sRGB."""
    plt = _plt()
    real = lab_to_srgb(vc.real_lab)
    sim = lab_to_srgb(vc.sim_lab)
    n = len(real)
    fig, ax = plt.subplots(figsize=(max(4.0, 0.55 * n + 1.2), 2.0))
    ax.imshow(np.stack([real, sim]), aspect="auto", interpolation="nearest")
    ax.set_yticks([0, 1], ["real", "simulated"])
    ax.set_xticks(range(n), [f"{x:g}" for x in vc.real.lengths_mm], fontsize=7)
    ax.set_xlabel("green length [mm]")
    ax.set_title(f"grass colour at {vc.label}", fontsize=9)
    fig.tight_layout()
    return fig


# ----------------------------------------------------------------------------- validate
def validation_sections(viewpoints: Sequence[ViewpointComparison], *, grid: bool = True
                        ) -> list[tuple[str, str]]:
    """Table, curves, grid (if the viewpoints span h x theta) and the reference calibration."""
    rows = [[v.label + (" (reference)" if v.reference else ""), f2(v.frechet), f2(v.max_error),
             f2(v.max_error_length_mm), f2(v.real_range), f2(v.sim_range),
             f2(v.calibration.r2_before, 3) if v.calibration else "-",
             f2(v.calibration.r2_after_real, 3) if v.calibration else "-",
             f2(v.calibration.r2_after_sim, 3) if v.calibration else "-", f2(v.sim_seconds)]
            for v in viewpoints]
    headers = ["viewpoint (h, d, theta)", "Frechet", "max OGCD error", "at length [mm]",
               "OGCD range real", "OGCD range sim", "R2 before", "R2 after (real)",
               "R2 after (sim)", "sim seconds"]
    out = [("Real vs simulated characteristic per viewpoint", table(headers, rows)),
           ("Characteristics", img_tag(figure_png(curves_figure(viewpoints)),
                                       "real vs simulated OGCD curves per viewpoint"))]
    hs = {v.viewpoint[0] for v in viewpoints}
    ts = {v.viewpoint[2] for v in viewpoints}
    if grid and len(hs) > 1 and len(ts) > 1 and len(viewpoints) >= 4:
        out.append(("Viewpoint grid (paper Figure 8)",
                    img_tag(figure_png(grid_figure(viewpoints)), "grid of viewpoints")))
    ref = next((v for v in viewpoints if v.reference), viewpoints[0])
    if np.isfinite(ref.real_lab).all() and np.isfinite(ref.sim_lab).all():
        out.append((f"Appearance at {ref.label} (paper Figure 9)",
                    img_tag(figure_png(appearance_figure(ref)),
                            "real and simulated grass colour per length")))
    if ref.calibration is not None:
        out.append((f"8-bit calibration at {ref.label} (paper Figure 11)",
                    img_tag(figure_png(calibration_figure(ref.calibration)),
                            "8-bit calibration scatter with regression lines")))
    return out


def validation_html(result: ValidationResult) -> str:
    """The ``grassd validate`` HTML report of a
    :class:`grassd.daemon.offline.validate.ValidationResult`."""
    r = result
    cam = r.real.camera
    info = table(["item", "value"], [
        ["capture", str(r.manifest.root)],
        ["camera", f"{cam.get('make', '')} {cam.get('model', '')} ({cam.get('cfa', '')})"],
        ["white balance from checker (R, G, B, G2)",
         ", ".join(f"{v:.3f}" for v in r.real.white_balance)],
        [f"colour correction M ({r.ccm.form}, virtual -> real)",
         "; ".join(" ".join(f"{v:.3f}" for v in row) for row in r.ccm.matrix)],
        ["checker error after M, each patch left out (mean / max dE00)",
         "{:.2f} / {:.2f}".format(*r.ccm.reported_de00)],
        ["simulation read through", chain_text(r.chain)],
        ["light", f"{r.manifest.light.hdri.name}, {r.manifest.light.ambient_lux:g} lx"],
        ["render settings", ", ".join(f"{k} {v}" for k, v in r.settings.items())],
        ["seconds", ", ".join(f"{k} {v:.1f}" for k, v in r.seconds.items())],
    ], left=2)
    sections = [("Capture", info)] + validation_sections(r.viewpoints)
    if r.repeatability:
        sections.append(("Repeatability of the real pixel (paper: mean OGCD std 0.42)", table(
            ["viewpoint", "trials", "mean std of OGCD"],
            [[k, v["trials"], f2(v["mean_std_ogcd"], 3)] for k, v in r.repeatability.items()])))
    return page("grassd validate: real vs simulated grass colour characteristic", sections,
                intro="Discrete Frechet distance and maximum OGCD error between the measured "
                      "and the simulated characteristic (paper section 4; paper reference "
                      "viewpoint: Frechet 1.16, maximum error 1.51).")


# ----------------------------------------------------------------------------- fit
START_COLOUR = "#888888"


def fit_figure(viewpoints: Sequence[ViewpointFit]) -> Figure:
    """Real, starting and fitted OGCD vs length per viewpoint of a ``grassd fit`` result
    (held-out viewpoints marked in the title)."""
    fig, axes = _panels(len(viewpoints), 4, (3.3, 2.9))
    for ax, v in zip(axes, viewpoints, strict=True):
        x = v.fitted.real.lengths_mm
        ax.plot(x, v.fitted.real.ogcd, "o-", color=REAL_COLOUR, ms=4, label="real")
        ax.plot(x, v.start.sim.ogcd, "s--", color=START_COLOUR, ms=3, label="start")
        ax.errorbar(x, v.fitted.sim.ogcd, yerr=v.fitted.sim.ogcd_stderr, fmt="s-",
                    color=SIM_COLOUR, ms=3, capsize=2, label="fitted")
        ax.set_title(v.fitted.label + (" held out" if v.held_out else ""), fontsize=9)
        ax.text(0.03, 0.95, f"F start {v.start.frechet:.2f}\nF fitted {v.fitted.frechet:.2f}",
                transform=ax.transAxes, va="top", fontsize=8)
        ax.set_xlabel("green length [mm]")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8, loc="lower right")
    fig.tight_layout()
    return fig


def fit_html(result: FitResult) -> str:
    """The ``grassd fit`` HTML report of a :class:`grassd.daemon.offline.fit.FitResult`."""
    params = table(["field", "start", "fitted", "standard error"], result.rows())
    views = table(["viewpoint (h, d, theta)", "held out", "Frechet start", "Frechet fitted",
                   "max error start", "max error fitted"],
                  [[v.fitted.label,
                    "yes" if v.held_out else "", f2(v.start.frechet), f2(v.fitted.frechet),
                    f2(v.start.max_error), f2(v.fitted.max_error)] for v in result.viewpoints])
    sections = [("Fitted materials", params), ("Per viewpoint", views),
                ("Characteristics", img_tag(figure_png(fit_figure(result.viewpoints)),
                                            "real, starting and fitted OGCD per viewpoint"))]
    if result.notes:
        sections.append(("Notes", "".join(f"<p class=\"note\">{html.escape(n)}</p>"
                                          for n in result.notes)))
    sections.append(("[display.pixel] for grassd.toml",
                     f"<pre>{html.escape(result.to_toml())}</pre>"))
    return page("grassd fit: the pixel's materials from photos", sections,
                intro=f"Fitted to {sum(not v.held_out for v in result.viewpoints)} viewpoint(s), "
                      f"chi2 {result.chi2:.1f} on {result.dof} degrees of freedom, "
                      f"{result.seconds:.1f} s, read through {chain_text(result.chain)}. "
                      "Simulated curves average "
                      f"{result.settings.layouts} random tuft layouts.")
