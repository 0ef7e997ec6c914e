"""``grassd experiment paper``: the paper's simulation experiments (section 4) end to end.

* Multiple viewpoints (paper 4.1, Figure 8, Table 1): the 16 viewpoints h in 150/160/170/180 cm
  x theta in 0/30/60/90 deg at d = 2 m, in an indoor environment, with M fitted once from the
  checker (the reference viewpoint is (170, 2, 0)); timings per viewpoint and for all 16.
* Multiple environments (paper 4.2, Figure 9): the reference viewpoint in five environments,
  mapped onto the bundled HDRIs (:data:`ENVIRONMENTS`).
* 8-bit calibration (paper 6.2, Figure 11): R^2 before and after, with the real and with the
  simulated characteristic, at the reference viewpoint.
* Repeatability (paper 4.1.1): the reference viewpoint measured in several trials; mean over
  lengths of the standard deviation of the real OGCD (paper: 0.42 over 10 trials).

No real capture ships with the project, so the "real" side is a stand-in: a world that differs
from the simulation model where the paper says reality differed (green blades that splay as
they grow, :data:`REAL_SPLAY_DEG`; paper section 4.1.3) and whose blades lie elsewhere
(:data:`REAL_LAYOUT_SEED`; in each repeated trial elsewhere again), photographed by the virtual
camera (:mod:`grassd.daemon.offline.virtual_capture`) and measured by ``grassd validate``'s
real-capture path. Our numbers therefore measure the whole pipeline against a known, physically
rendered truth; the paper's numbers (:data:`PAPER`) are printed beside them where the paper
states them.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, TypedDict

import numpy as np

from grassd.daemon.offline.validate import (
    MissingPhotoError,
    Repeatability,
    ValidateError,
    ViewpointComparison,
    ViewpointReport,
    default_renderer,
    load_manifest,
    validate_capture,
)
from grassd.sim.light_input import LightInput

if TYPE_CHECKING:
    from grassd.sim.renderer import Renderer

#: Blade splay of the stand-in real pixel at full length (deg): the paper's stated cause of its
#: theta = 90 deg error (real green blades spread out as they grow).
REAL_SPLAY_DEG: float = 15.0
#: The paper's 16 viewpoints (h cm, d m, theta deg), reference first.
VIEWPOINTS: tuple[tuple[float, float, float], ...] = tuple(
    sorted(((h, 2.0, t) for h in (150.0, 160.0, 170.0, 180.0) for t in (0.0, 30.0, 60.0, 90.0)),
           key=lambda v: (v != (170.0, 2.0, 0.0), v)))
REFERENCE: tuple[float, float, float] = (170.0, 2.0, 0.0)
#: Blade layout of the stand-in real pixel: its blades do not sit where the model's do.
REAL_LAYOUT_SEED: int = 101


@dataclass(frozen=True)
class Environment:
    """A paper environment mapped onto a bundled HDRI (``light.hdri``: its file name), with
    plausible lux readings."""

    key: str
    name: str
    light: LightInput

    def light_in(self, hdri_dir: Path) -> LightInput:
        """The light of this environment, its HDRI in ``hdri_dir``."""
        return replace(self.light, hdri=hdri_dir / self.light.hdri)


#: Paper section 4.2's five environments on the bundled HDRIs (see shared/hdri/LICENSE.txt).
ENVIRONMENTS: tuple[Environment, ...] = (
    Environment("Env 1", "standard colour evaluation (ISO 3664, 2000 lx)",
                LightInput(Path("studio.exr"), 2000.0)),
    Environment("Env 2", "indoor with natural light", LightInput(Path("interior.exr"), 500.0)),
    Environment("Env 3", "tree-shaded area", LightInput(Path("forest.exr"), 6000.0)),
    Environment("Env 4", "paved courtyard with direct sun (directional light)",
                LightInput(Path("courtyard.exr"), 12000.0, sun_lux=45000.0,
                           sun_azimuth_deg=200.0, sun_elevation_deg=45.0)),
    Environment("Env 5", "open area, sun inside the HDRI",
                LightInput(Path("city.exr"), 70000.0, sun_from_hdri=True)),
)
#: The environment of the multi-viewpoint experiment (the paper used a classroom).
MULTIVIEW_ENV: str = "Env 2"

class PaperComparison(TypedDict):
    """A comparison the paper states: Frechet distance and maximum OGCD error (dE00), and the
    length (mm) of that error where the paper gives it."""

    frechet: float
    max_error: float
    at_mm: float | None


class _PaperFigures(TypedDict):
    """The numbers the paper states but its comparisons per viewpoint: per environment,
    seconds, hours, the real pixel's OGCD spread (dE00) and the 8-bit calibration's R^2."""

    environments: dict[str, PaperComparison]
    seconds_per_viewpoint: float
    seconds_16_viewpoints: float
    manual_seconds_per_viewpoint: float
    offline_method_frechet: float
    offline_method_hours: float
    real_repeatability_ogcd_std: float
    r2_before: float
    r2_after_real: float
    r2_after_sim: float


class PaperNumbers(_PaperFigures):
    """The numbers the paper states (:data:`PAPER`), its comparisons per viewpoint (h cm, d m,
    theta deg) among them."""

    viewpoints: dict[tuple[float, float, float], PaperComparison]


class PaperReport(_PaperFigures):
    """:data:`PAPER` in JSON: the viewpoints' keys written as ``[h, d, theta]`` lists."""

    viewpoints: dict[str, PaperComparison]


#: Numbers the paper states (section 4 and 6.2). Frechet / max OGCD error / at length (mm).
PAPER: PaperNumbers = {
    "viewpoints": {
        (170.0, 2.0, 0.0): {"frechet": 1.16, "max_error": 1.51, "at_mm": 6.69},
        (150.0, 2.0, 0.0): {"frechet": 2.42, "max_error": 2.42, "at_mm": None},
        (160.0, 2.0, 0.0): {"frechet": 1.26, "max_error": 2.08, "at_mm": 15.11},
        (180.0, 2.0, 0.0): {"frechet": 2.06, "max_error": 2.21, "at_mm": 13.99},
    },
    "environments": {
        "Env 1": {"frechet": 2.79, "max_error": 2.95, "at_mm": 19.48},
        "Env 2": {"frechet": 1.99, "max_error": 2.56, "at_mm": 8.86},
        "Env 3": {"frechet": 1.20, "max_error": 1.88, "at_mm": 7.90},
        "Env 4": {"frechet": 1.85, "max_error": 2.30, "at_mm": 7.21},
        "Env 5": {"frechet": 1.91, "max_error": 4.22, "at_mm": 14.11},
    },
    "seconds_per_viewpoint": 5.0, "seconds_16_viewpoints": 80.0,
    "manual_seconds_per_viewpoint": 300.0, "offline_method_frechet": 1.71,
    "offline_method_hours": 40.0, "real_repeatability_ogcd_std": 0.42,
    "r2_before": 0.956, "r2_after_real": 0.999, "r2_after_sim": 0.965,
}


class RunReport(TypedDict):
    """The sizes of an experiment's run in JSON (:class:`ExperimentSettings`)."""

    lengths_mm: list[float]
    samples: int
    replicates: int
    photo_width: int
    photo_spp: int
    real_splay_deg: float
    trials: int
    seed: int


class NotMeasured(TypedDict):
    """An empty object: what was not measured (the repeatability of one trial)."""


class ExperimentReport(TypedDict):
    """The JSON report of ``grassd experiment paper`` (:meth:`ExperimentResult.to_json`)."""

    settings: RunReport
    viewpoints: list[ViewpointReport]
    environments: dict[str, ViewpointReport]
    seconds: dict[str, float]
    notes: list[str]
    repeatability: Repeatability | NotMeasured
    paper: PaperReport


@dataclass(frozen=True)
class ExperimentSettings:
    """Sizes of the run. ``quick()`` is for tests and smoke runs (seconds, not minutes)."""

    lengths_mm: tuple[float, ...] = tuple(float(x) for x in range(21))
    samples: int = 4096
    replicates: int = 8
    photo_width: int = 128
    photo_spp: int = 16
    viewpoints: tuple[tuple[float, float, float], ...] = VIEWPOINTS
    environments: tuple[str, ...] = tuple(e.key for e in ENVIRONMENTS)
    real_splay_deg: float = REAL_SPLAY_DEG
    trials: int = 3
    seed: int = 0

    @classmethod
    def quick(cls) -> ExperimentSettings:
        """5 lengths, 1024 paths x 4 replicates, 64-pixel photos at 4 spp, 2 trials."""
        return cls(lengths_mm=(0.0, 5.0, 10.0, 15.0, 20.0), samples=1024, replicates=4,
                   photo_width=64, photo_spp=4, trials=2)


@dataclass
class ExperimentResult:
    """Comparisons per viewpoint (multi-view environment) and per environment, and timings."""

    settings: ExperimentSettings
    viewpoints: list[ViewpointComparison] = field(default_factory=list)
    environments: dict[str, ViewpointComparison] = field(default_factory=dict)
    seconds: dict[str, float] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    repeatability: Repeatability | None = None

    @property
    def reference(self) -> ViewpointComparison:
        """The multi-view environment's reference viewpoint."""
        return next(v for v in self.viewpoints if v.reference)

    def sim_seconds_per_viewpoint(self) -> float:
        """Mean simulation seconds of one viewpoint (all lengths)."""
        return float(np.mean([v.sim_seconds for v in self.viewpoints]))

    def to_json(self) -> ExperimentReport:
        """JSON report."""
        s = self.settings
        p = PAPER
        return {
            "settings": {"lengths_mm": list(s.lengths_mm), "samples": s.samples,
                         "replicates": s.replicates, "photo_width": s.photo_width,
                         "photo_spp": s.photo_spp, "real_splay_deg": s.real_splay_deg,
                         "trials": s.trials, "seed": s.seed},
            "viewpoints": [v.to_json() for v in self.viewpoints],
            "environments": {k: v.to_json() for k, v in self.environments.items()},
            "seconds": self.seconds, "notes": self.notes,
            "repeatability": (NotMeasured() if self.repeatability is None
                              else self.repeatability),
            "paper": {
                "environments": p["environments"],
                "seconds_per_viewpoint": p["seconds_per_viewpoint"],
                "seconds_16_viewpoints": p["seconds_16_viewpoints"],
                "manual_seconds_per_viewpoint": p["manual_seconds_per_viewpoint"],
                "offline_method_frechet": p["offline_method_frechet"],
                "offline_method_hours": p["offline_method_hours"],
                "real_repeatability_ogcd_std": p["real_repeatability_ogcd_std"],
                "r2_before": p["r2_before"], "r2_after_real": p["r2_after_real"],
                "r2_after_sim": p["r2_after_sim"],
                "viewpoints": {str(list(k)): v for k, v in p["viewpoints"].items()}},
        }


def run_paper(out_dir: str | Path, *, settings: ExperimentSettings | None = None,
              hdri_dir: str | Path, renderer: Renderer | None = None,
              progress: Callable[[str], None] | None = None) -> ExperimentResult:
    """Run the paper's experiments; capture directories go under ``out_dir``.

    ``hdri_dir`` holds the environments' panoramas (:data:`ENVIRONMENTS`: studio, interior,
    forest, courtyard and city.exr). None ship with the package: the project keeps CC0 ones in
    its ``shared/hdri`` folder, beside the sources."""
    from grassd.daemon.offline.virtual_capture import capture_world
    from grassd.sim.scene import PixelSpec, RenderSettings

    st = settings or ExperimentSettings()
    hdri = Path(hdri_dir)
    envs = {e.key: e for e in ENVIRONMENTS}
    unknown = [k for k in st.environments if k not in envs]
    if unknown:
        raise ValidateError(f"unknown environment(s) {unknown}; use {list(envs)}")
    for key in st.environments:
        path = envs[key].light_in(hdri).hdri
        if not path.is_file():
            raise MissingPhotoError(f"HDRI {path} for {key} does not exist; "
                                    "give --hdri-dir with the bundled panoramas")
    if renderer is None:
        renderer = default_renderer()
    out = Path(out_dir)
    rs = RenderSettings(samples=st.samples, replicates=st.replicates, seed=st.seed)
    real = PixelSpec(splay_deg=st.real_splay_deg, layout_seed=REAL_LAYOUT_SEED)
    result = ExperimentResult(settings=st)
    t_all = time.perf_counter()
    capture_s = validate_s = 0.0
    for key in st.environments:
        env = envs[key]
        light = env.light_in(hdri)
        lighting = light.lighting()
        result.notes += [f"{key}: {n}" for n in lighting.notes]
        views = list(st.viewpoints) if key == MULTIVIEW_ENV else [REFERENCE]
        if REFERENCE in views:  # the reference viewpoint first: it is the series M belongs to
            views.remove(REFERENCE)
            views.insert(0, REFERENCE)
        t0 = time.perf_counter()
        capture_world(out / key.replace(" ", "").lower(), light, views, st.lengths_mm,
                      real_pixel=real, renderer=renderer, lighting=lighting,
                      width=st.photo_width, spp=st.photo_spp, seed=st.seed,
                      extra_trials=max(st.trials - 1, 0) if key == MULTIVIEW_ENV else 0,
                      progress=(lambda m, k=key: progress(f"{k}: {m}")) if progress else None)
        t1 = time.perf_counter()
        manifest = load_manifest(out / key.replace(" ", "").lower())
        res = validate_capture(manifest, renderer=renderer, settings=rs, lighting=lighting,
                               progress=(lambda m, k=key: progress(f"{k}: {m}"))
                               if progress else None)
        t2 = time.perf_counter()
        capture_s += t1 - t0
        validate_s += t2 - t1
        if key == MULTIVIEW_ENV:
            first: dict[tuple, ViewpointComparison] = {}
            for v in res.viewpoints:  # repeated trials: the first one enters the tables
                first.setdefault(tuple(v.viewpoint), v)
            result.viewpoints = list(first.values())
            result.repeatability = res.repeatability.get(res.reference.label)
        result.environments[key] = res.reference
    result.seconds = {"capture_stand_in_real": capture_s, "validate": validate_s}
    if result.viewpoints:
        result.seconds[f"simulate_{len(result.viewpoints)}_viewpoints"] = float(
            sum(v.sim_seconds for v in result.viewpoints))
    result.seconds["total"] = time.perf_counter() - t_all
    return result


# ----------------------------------------------------------------------------- tables
def _paper(v: float | None, digits: int = 2) -> str:
    return "-" if v is None else f"{v:.{digits}f}"


def viewpoint_rows(result: ExperimentResult) -> list[list[str]]:
    """Rows of the multi-viewpoint table (ours beside the paper's)."""
    rows = []
    for v in sorted(result.viewpoints, key=lambda c: (c.viewpoint[2], c.viewpoint[0])):
        p = PAPER["viewpoints"].get(v.viewpoint)
        paper = (None, None, None) if p is None else (p["frechet"], p["max_error"], p["at_mm"])
        rows.append([f"{v.viewpoint[0]:g}", f"{v.viewpoint[2]:g}", f"{v.frechet:.2f}",
                     _paper(paper[0]), f"{v.max_error:.2f}",
                     _paper(paper[1]), f"{v.max_error_length_mm:.1f}",
                     _paper(paper[2]), f"{v.real_range:.2f}", f"{v.sim_range:.2f}",
                     f"{v.sim_seconds:.2f}"])
    return rows


VIEWPOINT_HEADERS = ["h cm", "theta deg", "Frechet", "paper", "max err", "paper", "at mm",
                     "paper", "range real", "range sim", "sim s"]
ENV_HEADERS = ["env", "HDRI", "Frechet", "paper", "max err", "paper", "at mm", "paper",
               "range real", "range sim", "sim s"]


def environment_rows(result: ExperimentResult) -> list[list[str]]:
    """Rows of the multi-environment table."""
    envs = {e.key: e for e in ENVIRONMENTS}
    rows = []
    for key, v in result.environments.items():
        p = PAPER["environments"][key]
        rows.append([key, str(envs[key].light.hdri), f"{v.frechet:.2f}", _paper(p["frechet"]),
                     f"{v.max_error:.2f}", _paper(p["max_error"]),
                     f"{v.max_error_length_mm:.1f}", _paper(p["at_mm"]), f"{v.real_range:.2f}",
                     f"{v.sim_range:.2f}", f"{v.sim_seconds:.2f}"])
    return rows


def timing_rows(result: ExperimentResult) -> list[list[str]]:
    """Rows of the paper's Table 1 (measurement times)."""
    per = result.sim_seconds_per_viewpoint() if result.viewpoints else float("nan")
    n = len(result.viewpoints)
    return [["per viewpoint", "about 5 min", f"about {PAPER['seconds_per_viewpoint']:g} s",
             f"{per:.2f} s"],
            [f"total for {n} viewpoints", "about 80 min",
             f"about {PAPER['seconds_16_viewpoints']:g} s",
             f"{result.seconds.get(f'simulate_{n}_viewpoints', float('nan')):.1f} s"]]


TIMING_HEADERS = ["", "manual (paper)", "paper's method", "grassd (this run)"]
CAL_HEADERS = ["", "R2 before", "R2 after (real)", "R2 after (sim)"]


def repeatability_line(result: ExperimentResult) -> str:
    """The repeatability test's result beside the paper's 0.42."""
    r = result.repeatability
    if not r:
        return "repeatability: not measured (one trial)"
    return (f"repeatability at {result.reference.label}: mean std of OGCD "
            f"{r['mean_std_ogcd']:.3f} over {r['trials']} trials of the stand-in real pixel "
            f"(paper, real pixel, 10 trials: {PAPER['real_repeatability_ogcd_std']:g})")


def calibration_rows(result: ExperimentResult) -> list[list[str]]:
    """The paper's Figure 11 numbers beside ours at the reference viewpoint."""
    cal = result.reference.calibration
    ours = (["grassd (stand-in real)", f"{cal.r2_before:.3f}", f"{cal.r2_after_real:.3f}",
             f"{cal.r2_after_sim:.3f}"] if cal else ["grassd", "-", "-", "-"])
    return [ours, ["paper", f"{PAPER['r2_before']:.3f}", f"{PAPER['r2_after_real']:.3f}",
                   f"{PAPER['r2_after_sim']:.3f}"]]


COMPARE_HEADERS = ["method", "Frechet at (170, 2, 0)", "time per viewpoint"]


def comparison_rows(result: ExperimentResult) -> list[list[str]]:
    """The paper's comparative experiment: our Frechet distance and time beside the paper's
    real-time method and the offline-rendering method it compares with."""
    return [["grassd (stand-in real)", f"{result.reference.frechet:.2f}",
             f"{result.sim_seconds_per_viewpoint():.2f} s"],
            ["paper (Unity HDRP, real-time)", f"{PAPER['viewpoints'][REFERENCE]['frechet']:.2f}",
             f"about {PAPER['seconds_per_viewpoint']:g} s"],
            ["offline rendering + GA (Mizuno et al.)", f"{PAPER['offline_method_frechet']:.2f}",
             f"about {PAPER['offline_method_hours']:g} h"]]


def format_table(headers: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    """Plain-text table with right-aligned columns."""
    widths = [max(len(str(h)), *(len(str(r[i])) for r in rows)) for i, h in enumerate(headers)]
    line = "  ".join(str(h).rjust(w) for h, w in zip(headers, widths, strict=True))
    body = ["  ".join(str(c).rjust(w) for c, w in zip(r, widths, strict=True)) for r in rows]
    return "\n".join([line, "-" * len(line), *body])


def text_report(result: ExperimentResult) -> str:
    """The tables ``grassd experiment paper`` prints."""
    parts = []
    if result.viewpoints:
        parts += [f"Multiple viewpoints ({MULTIVIEW_ENV}; paper section 4.1, Figure 8)",
                  format_table(VIEWPOINT_HEADERS, viewpoint_rows(result)), "",
                  "Measurement times (paper Table 1)",
                  format_table(TIMING_HEADERS, timing_rows(result)), "",
                  f"8-bit calibration at {result.reference.label} (paper Figure 11)",
                  format_table(CAL_HEADERS, calibration_rows(result)), "",
                  repeatability_line(result), ""]
    if result.viewpoints:
        parts += ["Comparative experiment at (170, 2, 0) (paper section 4.3)",
                  format_table(COMPARE_HEADERS, comparison_rows(result)), ""]
    if result.environments:
        parts += ["Multiple environments at (170, 2, 0) (paper section 4.2, Figure 9)",
                  format_table(ENV_HEADERS, environment_rows(result)), ""]
    parts.append("seconds: " + ", ".join(f"{k} {v:.1f}" for k, v in result.seconds.items()))
    return "\n".join(parts)


def experiment_html(result: ExperimentResult) -> str:
    """Self-contained HTML report: our numbers beside the paper's, with the paper's plots."""
    from grassd.daemon.offline import report

    st = result.settings
    intro = (
        "The paper's simulation experiments run by grassd on the bundled HDRIs. The 'real' "
        f"characteristic is a stand-in: a pixel whose green blades splay by {st.real_splay_deg:g}"
        " deg at full length (the paper's stated cause of its theta = 90 deg error) and whose "
        "blades rest elsewhere than the model's, photographed by the virtual camera into DNGs "
        "and measured through grassd validate's real-capture path; the simulation model has "
        "straight blades. Paper numbers are shown where the paper states them.")
    sections = []
    if result.viewpoints:
        sections += [
            (f"Multiple viewpoints ({MULTIVIEW_ENV}) - paper Figure 8",
             report.table(VIEWPOINT_HEADERS, viewpoint_rows(result), left=0)
             + report.img_tag(report.figure_png(report.grid_figure(result.viewpoints)),
                              "grid of 16 viewpoints, real vs simulated")),
            ("Measurement times - paper Table 1", report.table(TIMING_HEADERS,
                                                               timing_rows(result))),
            ("Repeatability - paper section 4.1.1", f"<p>{repeatability_line(result)}</p>"),
            ("Comparative experiment at (170, 2, 0) - paper section 4.3",
             report.table(COMPARE_HEADERS, comparison_rows(result))),
            (f"8-bit calibration at {result.reference.label} - paper Figure 11",
             report.table(CAL_HEADERS, calibration_rows(result))
             + (report.img_tag(report.figure_png(
                 report.calibration_figure(result.reference.calibration)),
                 "8-bit calibration scatter") if result.reference.calibration else "")),
        ]
    if result.environments:
        envs = list(result.environments.values())
        sections.append(("Multiple environments at (170, 2, 0) - paper Figure 9",
                         report.table(ENV_HEADERS, environment_rows(result))
                         + report.img_tag(report.figure_png(report.curves_figure(
                             envs, titles=list(result.environments))),
                             "real vs simulated per environment")))
    sections.append(("Run", report.table(["item", "value"], [
        ["lengths (mm)", ", ".join(f"{x:g}" for x in st.lengths_mm)],
        ["paths per length", f"{st.samples} x {st.replicates} replicates"],
        ["stand-in photos", f"{st.photo_width} px, {st.photo_spp} spp"],
        ["seconds", ", ".join(f"{k} {v:.1f}" for k, v in result.seconds.items())],
        ["notes", "; ".join(result.notes) or "-"]])))
    return report.page("grassd experiment paper", sections, intro=intro)
