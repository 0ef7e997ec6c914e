"""``grassd fit``: the grass pixel's materials from photos of it.

The capture directory is the one ``grassd validate`` reads (:mod:`grassd.daemon.offline.validate`):
RAW photos of the pixel at several green lengths from one or more viewpoints, the checker photo
and the light. The fit finds the :class:`~grassd.sim.scene.PixelSpec` fields that make the
simulated photos match the real ones: the yellow, green and base albedos (8-bit encoded sRGB, as
the config writes them), the glossy lobe (``specular``, ``smoothness``) and the green blades'
``splay_deg``.

How (fast by construction, every sample kept):

* **Albedos and specular: one render, then milliseconds.** With the paths' random numbers
  fixed, the radiance is a polynomial in the materials' reflectances and ``ks`` whose
  coefficients the renderer records once per viewpoint
  (:meth:`grassd.sim.renderer.Renderer.albedo_terms`, after Ben-Artzi et al. 2008). A
  candidate's photos are then a contraction of those coefficients, and a Gauss-Newton fit
  (:func:`scipy.optimize.least_squares`) of CIELAB residuals over every fitted photo takes a
  few milliseconds.
* **Splay and smoothness: re-rendered.** They move the geometry and the lobe's shape, which no
  polynomial holds: each candidate value is recorded anew (the same random numbers: common
  random numbers make the comparison between candidates smooth), the albedos fitted inside it,
  and the profile of the misfit over a coarse grid is refined by successive parabolas through
  its lowest point and its neighbours (:func:`_next_candidate`). Smoothness is searched
  coarsely, then splay, then smoothness again near its best at the fitted splay, to
  :data:`REFINE_TOLERANCE`: a base hidden under the blades takes its colour from what the lobe
  leaves over, so it follows the lobe's shape closely (the olive test pixel's base blue moves
  about 3 levels per 0.01 of smoothness).
* **The layout.** The model's tufts are random; the photographed pixel's are one accident. The
  simulation is averaged over ``layouts`` random layouts, and their spread (per viewpoint and
  CIELAB component) weighs the residuals next to the Monte Carlo error and a floor for the
  photos' own noise, so that no parameter bends to one layout.
* **Uncertainty.** The real pixel is one layout seen in every photo, so its accident is
  shared by all residuals. Albedos and specular: the Gauss-Newton covariance ``(J^T J)^-1``
  (scaled by the reduced chi-square where it exceeds 1) plus the spread of the fits that take
  each simulated layout in turn for the photographed one (a layout jackknife). Splay and
  smoothness: where the profile of the misfit rises above its minimum by the reduced
  chi-square (at least 1) times the albedos' inflation by the jackknife, interpolated between
  the candidates tried. The albedos and specular fitted at the best splay and smoothness
  move with them, so their covariance also takes ``g g^T se^2`` per re-rendered parameter,
  ``g`` the albedos' slope along its profile (the fits at the candidates tried nearest on
  either side) and ``se`` its standard error (the olive test pixel's base blue: about 3
  levels per 0.01 of smoothness).
* **Priors.** A fitted parameter the photos do not determine (its standard error past
  :data:`MAX_STDERR`) is held at its prior: the ``[pixel]`` value with the error of
  :data:`PRIOR_STDERR`, a pseudo-residual ``(value - start) / error`` beside the photos' (for
  the splay and smoothness, its square added to the misfit of each candidate); the fit runs
  again with the rest still fitted and a note names it. Only a fit that determines nothing is
  refused.
* **Judging.** Every viewpoint's real OGCD is compared with the starting model's and the
  fitted one's (discrete Frechet distance and largest OGCD error, as ``validate``); held-out
  viewpoints (``holdout``) take no part in the fit and show how well it predicts a view it
  never saw.

Units: albedos 8-bit encoded sRGB (0..255), ``specular`` 0..1, ``smoothness`` 0..0.97,
``splay_deg`` degrees, lengths mm, colour differences CIEDE2000.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, TypedDict

import numpy as np
import tomli_w
from colour import delta_E
from numpy.typing import NDArray

from grassd.calib.charts import get_chart
from grassd.daemon.core.calibration.simulation import layout_display, layout_seed
from grassd.daemon.offline.colour_chain import ColourChain, simulation_chain
from grassd.daemon.offline.fit_config import FitSettings
from grassd.daemon.offline.validate import (
    CaptureManifest,
    RealCapture,
    ValidateError,
    ViewpointComparison,
    compare_viewpoint,
    default_renderer,
    measure_and_correct,
)
from grassd.sim.albedo_terms import check_lobe
from grassd.sim.scene import srgb_to_linear

if TYPE_CHECKING:
    from grassd.daemon.core.config.settings import PixelValue
    from grassd.sim.albedo_terms import AlbedoTerms
    from grassd.sim.lighting import Lighting
    from grassd.sim.renderer import Renderer
    from grassd.sim.scene import PixelSpec

#: The fitted PixelSpec fields, by their config names, in the order they are reported.
FIT_PARAMS: tuple[str, ...] = ("yellow_srgb", "green_srgb", "base_srgb", "specular",
                               "smoothness", "splay_deg")
#: Albedo fields and their material rows in the renderer (yellow, green, base; cavity fixed).
ALBEDO_ROWS: dict[str, int] = {"yellow_srgb": 0, "green_srgb": 1, "base_srgb": 2}
#: Candidate splays (deg) of the coarse profile; the parabola refines between them.
SPLAY_GRID: tuple[float, ...] = (0.0, 4.0, 8.0, 12.0, 16.0)
#: Candidate smoothnesses of the coarse profile.
SMOOTHNESS_GRID: tuple[float, ...] = (0.3, 0.5, 0.7, 0.85)
#: Spacing of the fine smoothness profile around the coarse minimum (at the fitted splay).
SMOOTHNESS_STEP: float = 0.1
#: Most parabolic refinements of a profile, and when a candidate is close enough to one tried.
MAX_REFINE: int = 4
REFINE_TOLERANCE: dict[str, float] = {"smoothness": 0.01, "splay_deg": 0.5}
#: Reference ``ks`` the paths are sampled with when ``specular`` is fitted from a start of 0:
#: the glossy lobe is then sampled too (any ``ks`` is evaluated from the same paths).
SAMPLING_SPECULAR: float = 0.05
#: Photos must show green at least this long (fraction of ``green_max_mm``) to tell splay.
SPLAY_MIN_LENGTH_FRACTION: float = 0.4
#: Below this fitted ``specular`` the lobe's shape (``smoothness``) cannot be seen.
MIN_VISIBLE_SPECULAR: float = 0.01
#: A parameter whose standard error exceeds this is not determined by the photos.
MAX_STDERR: dict[str, float] = {"yellow_srgb": 25.0, "green_srgb": 25.0, "base_srgb": 25.0,
                                "specular": 0.2, "smoothness": 0.3, "splay_deg": 6.0}
#: What a ``[pixel]`` value is taken to be known to (its standard error, in the parameter's
#: units) where the photos do not determine it: the fit then holds it at that prior, a
#: pseudo-observation of the value with this error beside the photos, and fits the rest. A
#: prior as wide as :data:`MAX_STDERR`: a parameter known that well counts as determined.
PRIOR_STDERR: dict[str, float] = dict(MAX_STDERR)
#: Photos whose median CIEDE2000 from the fitted model exceeds this contradict each other (or
#: the model): no materials make them agree.
CONTRADICTION_DE00: float = 4.0


class FitError(ValidateError):
    """The materials cannot be fitted from this capture; the message says what to change."""


class NotIdentifiableError(FitError):
    """The photos do not determine a parameter (too few lengths or viewpoints): ``parameter``
    (a :data:`FIT_PARAMS` name; None where no single one is to blame)."""

    def __init__(self, message: str, parameter: str | None = None) -> None:
        super().__init__(message)
        self.parameter = parameter


class ContradictoryPhotosError(FitError):
    """No materials make the simulation agree with the photos."""


class FitNotConvergedError(FitError):
    """The least-squares fit stopped before it converged."""


class StartAndFitted(TypedDict):
    """A measure of the starting and of the fitted model."""

    start: float
    fitted: float


class ViewpointFitReport(TypedDict):
    """The JSON of a :class:`ViewpointFit` (lengths mm, OGCD per length)."""

    series: int
    viewpoint: list[float]
    held_out: bool
    frechet: StartAndFitted
    max_error: StartAndFitted
    lengths_mm: list[float]
    real_ogcd: list[float]
    start_ogcd: list[float]
    fitted_ogcd: list[float]


class FitReport(TypedDict):
    """The JSON report of ``grassd fit`` (:meth:`FitResult.to_json`)."""

    pixel: dict[str, float | list[float]]
    stderr: dict[str, float | list[float] | None]
    start: dict[str, float | list[float]]
    viewpoints: list[ViewpointFitReport]
    chi2: float
    dof: int
    notes: list[str]
    profile: dict[str, list[list[float]]]
    settings: dict[str, float]
    colour_chain: str
    seconds: float


@dataclass(frozen=True)
class ViewpointFit:
    """One viewpoint judged: the real OGCD against the starting and the fitted model."""

    series: int  # index of the capture's [[series]] (repeated trials share a viewpoint)
    viewpoint: tuple[float, float, float]
    held_out: bool
    start: ViewpointComparison
    fitted: ViewpointComparison

    def to_json(self) -> ViewpointFitReport:
        """``series``, ``viewpoint``, ``held_out``, ``frechet`` and ``max_error`` (start,
        fitted), and the curves."""
        return {
            "series": self.series, "viewpoint": list(self.viewpoint), "held_out": self.held_out,
            "frechet": {"start": self.start.frechet, "fitted": self.fitted.frechet},
            "max_error": {"start": self.start.max_error, "fitted": self.fitted.max_error},
            "lengths_mm": self.fitted.real.lengths_mm.tolist(),
            "real_ogcd": self.fitted.real.ogcd.tolist(),
            "start_ogcd": self.start.sim.ogcd.tolist(),
            "fitted_ogcd": self.fitted.sim.ogcd.tolist(),
        }


@dataclass(frozen=True)
class FitResult:
    """What ``grassd fit`` reports. ``pixel``: the fitted fields (config names; albedos as
    8-bit sRGB lists); ``stderr``: their standard errors, same keys; ``start``: the model's
    PixelSpec fields the fit started from (manifest ``[pixel]`` over the defaults);
    ``notes``: what the fit could not determine and kept; ``profile``: per re-rendered
    parameter the (value, misfit) pairs tried."""

    pixel: dict[str, float | list[float]]
    stderr: dict[str, float | list[float] | None]
    start: dict[str, float | list[float]]
    viewpoints: tuple[ViewpointFit, ...]
    chi2: float
    dof: int
    seconds: float
    settings: FitSettings
    #: how the simulation was read (:mod:`grassd.daemon.offline.colour_chain`): the checker
    #: correction's form, or "camera" (the camera's sensitivities, no correction)
    chain: str
    notes: tuple[str, ...] = ()
    profile: dict[str, list[tuple[float, float]]] = field(default_factory=dict)

    def to_json(self) -> FitReport:
        """The JSON report."""
        return {
            "pixel": self.pixel, "stderr": self.stderr, "start": self.start,
            "viewpoints": [v.to_json() for v in self.viewpoints],
            "chi2": self.chi2, "dof": self.dof, "notes": list(self.notes),
            "profile": {k: [list(p) for p in v] for k, v in self.profile.items()},
            "settings": {k: getattr(self.settings, k) for k in FitSettings.__dataclass_fields__},
            "colour_chain": self.chain, "seconds": self.seconds,
        }

    def rows(self) -> list[list[str]]:
        """Per fitted field: its name, start, fitted value and standard error as text (albedo
        channels to 0.1 level, "-" for no standard error), for the CLI and HTML tables."""

        def text(v: float | list[float] | None) -> str:
            if v is None:
                return "-"
            return ", ".join(f"{c:.1f}" for c in v) if isinstance(v, list) else f"{v:.4g}"

        return [[k, text(self.start[k]), text(v), text(self.stderr.get(k))]
                for k, v in self.pixel.items()]

    def pixel_spec_fields(self) -> dict[str, PixelValue]:
        """The start's fields with the fitted ones over them (PixelSpec keyword arguments)."""
        out = {**self.start, **self.pixel}
        return {k: tuple(v) if isinstance(v, list) else v for k, v in out.items()}

    def to_toml(self) -> str:
        """A ``[display.pixel]`` table for grassd.toml: the capture's model with the fitted
        fields over it, standard errors as comments."""
        from grassd.sim.scene import PixelSpec

        default = PixelSpec()
        lines = ["# Fitted by grassd fit from photos of the pixel "
                 f"(chi2 {self.chi2:.1f} on {self.dof} degrees of freedom).",
                 "[display.pixel]"]
        for k, v in self.pixel_spec_fields().items():
            if k not in self.pixel and v == getattr(default, k):
                continue
            value = [round(float(c), 2) for c in v] if isinstance(v, tuple) else v
            if isinstance(value, float):
                value = round(value, 4)
            note = ""
            if k in self.stderr and self.stderr[k] is not None:
                se = self.stderr[k]
                note = "  # +- " + (", ".join(f"{s:.1f}" for s in se) if isinstance(se, list)
                                    else f"{se:.3g}")
            lines.append(tomli_w.dumps({k: value}).rstrip("\n") + note)
        return "\n".join(lines) + "\n"


def parse_params(text: str | None) -> tuple[str, ...]:
    """The fitted parameter names from ``--params`` (comma list; None: all of
    :data:`FIT_PARAMS`), in report order. Raises :class:`FitError` naming an unknown one."""
    if text is None:
        return FIT_PARAMS
    names = [p.strip() for p in text.split(",") if p.strip()]
    unknown = [p for p in names if p not in FIT_PARAMS]
    if unknown or not names:
        what = f"unknown {', '.join(unknown)}" if unknown else "names no parameter"
        raise FitError(f"--params {text!r}: {what}; choose from {', '.join(FIT_PARAMS)}")
    return tuple(p for p in FIT_PARAMS if p in names)


class _Model:
    """The simulated photos of a capture as a function of the pixel's materials: recorded
    terms per (shape, series), cached, and their CIELAB for any albedos and ``ks``."""

    def __init__(self, renderer: Renderer, lighting: Lighting, manifest: CaptureManifest,
                 chain: ColourChain, start: PixelSpec, settings: FitSettings,
                 glossy: bool) -> None:
        self.renderer, self.lighting, self.manifest = renderer, lighting, manifest
        self.chain, self.start, self.settings, self.glossy = chain, start, settings, glossy
        self.fit_series: list[int] = []  # recorded together whenever a shape is recorded
        self._cache: dict[tuple, list[AlbedoTerms]] = {}
        self._means: dict[tuple, NDArray[np.float64]] = {}  # mean coefficients (n, 56, 3)

    def _key(self, shape: tuple[float, float], series: int) -> tuple:
        """What a recording depends on: the shape and the series' viewpoint and lengths
        (repeated trials of one viewpoint share it)."""
        sr = self.manifest.series[series]
        return (shape, sr.viewpoint, tuple(sr.lengths_mm))

    def terms(self, shape: tuple[float, float], series: int) -> list[AlbedoTerms]:
        """The recorded terms of ``series`` at (smoothness, splay_deg), one per layout. A shape
        not yet recorded is recorded for every fitted series at once, layout by layout (the
        renderer then builds each layout's scene once)."""
        if self._key(shape, series) not in self._cache:
            self._record(shape, sorted({series, *self.fit_series}))
        return self._cache[self._key(shape, series)]

    def _record(self, shape: tuple[float, float], series: Sequence[int]) -> None:
        from grassd.sim.scene import DisplaySpec, RenderSettings, Viewpoint

        s = self.settings
        ref = replace(self.start, smoothness=shape[0], splay_deg=shape[1])
        if self.glossy and ref.specular == 0.0:
            ref = replace(ref, specular=SAMPLING_SPECULAR)
        todo = {self._key(shape, i): i for i in series}
        todo = {key: i for key, i in todo.items() if key not in self._cache}
        for key in todo:
            self._cache[key] = []
        for k in range(s.layouts):
            display = layout_display(DisplaySpec(ref), k)
            rs = RenderSettings(samples=s.samples, replicates=s.replicates,
                                max_bounces=s.max_bounces, seed=layout_seed(s.seed, k))
            for key, i in todo.items():
                sr = self.manifest.series[i]
                self._cache[key].append(self.renderer.albedo_terms(
                    display, self.lighting, Viewpoint(*sr.viewpoint), sr.lengths_mm, rs,
                    glossy=self.glossy))

    def replicates(self, shape: tuple[float, float], series: int, albedo: NDArray[np.float64],
                   ks: float) -> NDArray[np.float64]:
        """(layouts, replicates, n, 3) signals of the chain (:mod:`.colour_chain`)."""
        check_lobe(self.glossy, ks)
        terms = self.terms(shape, series)
        return self.chain.signal(np.stack([t.coefficients for t in terms]), albedo, ks,
                                 terms[0].degree)

    def mean(self, shape: tuple[float, float], series: int, albedo: NDArray[np.float64],
             ks: float, layouts: Sequence[int] | None = None) -> NDArray[np.float64]:
        """(n, 3) signal of the chain (:mod:`.colour_chain`) of the mean over ``layouts``
        (default all) and their replicates, the same as the chain's signal of
        ``replicates(...)[layouts].mean(axis=(0, 1))``: every chain's signal is linear in the
        coefficients, so their mean is kept per (shape, series, layouts) and a candidate costs
        one contraction (the fit's inner loop)."""
        terms = self.terms(shape, series)
        chosen = tuple(range(len(terms)) if layouts is None else layouts)
        key = (self._key(shape, series), chosen)
        if key not in self._means:
            self._means[key] = np.mean([terms[k].coefficients.mean(axis=0) for k in chosen],
                                       axis=0)
        return self.chain.signal(self._means[key], albedo, ks, terms[0].degree)

    def lab(self, signal: NDArray[np.float64]) -> NDArray[np.float64]:
        """CIELAB of the chain's signals, as the photos are read."""
        return self.chain.lab(signal)


@dataclass
class _Inner:
    """The albedo / specular fit at one shape: parameters, whitened residuals, Jacobian."""

    x: NDArray[np.float64]
    residuals: NDArray[np.float64]
    jac: NDArray[np.float64]
    cost: float  # sum of squared whitened residuals (chi-square)
    noise: float = 0.0  # the part of ``cost`` the simulation's own noise adds, expected

    @property
    def misfit(self) -> float:
        """``cost - noise``: what compares shapes recorded with different noise (a sharper
        lobe's glints are noisier, and noise alone raises chi-square)."""
        return self.cost - self.noise


class _Problem:
    """Fitted parameters in a flat vector (albedo triples in 8-bit sRGB, then ``ks``), the
    residuals of the fitted series, and the layout-aware weights."""

    def __init__(self, model: _Model, real: RealCapture, fit_series: Sequence[int],
                 params: Sequence[str]) -> None:
        self.model, self.real, self.fit_series = model, real, list(fit_series)
        self.albedo_params = [p for p in params if p in ALBEDO_ROWS]
        self.fit_ks = "specular" in params
        self.fixed_ks = float(model.start.specular)  # ks where it is not fitted
        start = model.start
        self.base_albedo = start.albedo_linear
        self.x0 = np.array([c for p in self.albedo_params for c in getattr(start, p)]
                           + ([start.specular] if self.fit_ks else []), dtype=np.float64)
        self.lower = np.array([0.0] * (3 * len(self.albedo_params))
                              + ([0.0] if self.fit_ks else []))
        self.upper = np.array([255.0] * (3 * len(self.albedo_params))
                              + ([0.9] if self.fit_ks else []))
        self.sigma: dict[int, NDArray[np.float64]] = {}
        #: parameters held at their prior (:data:`PRIOR_STDERR`) beside the photos
        self.priors: set[str] = set()
        self.start_shape = (float(start.smoothness), float(start.splay_deg))

    def prior_rows(self, x: NDArray[np.float64]) -> NDArray[np.float64]:
        """The priors' pseudo-residuals at ``x``: (value - start) / prior standard error per
        component of every albedo (and ``ks``) held at its prior."""
        rows = [(x[3 * i: 3 * i + 3] - self.x0[3 * i: 3 * i + 3]) / PRIOR_STDERR[p]
                for i, p in enumerate(self.albedo_params) if p in self.priors]
        if self.fit_ks and "specular" in self.priors:
            rows.append((x[-1:] - self.x0[-1:]) / PRIOR_STDERR["specular"])
        return np.concatenate(rows) if rows else np.zeros(0)

    def shape_prior(self, shape: tuple[float, float]) -> float:
        """The priors' chi-square at ``shape``: ((value - start) / prior standard error)^2 for
        smoothness and splay where held at their prior."""
        return float(sum(((shape[i] - self.start_shape[i]) / PRIOR_STDERR[name]) ** 2
                         for i, name in enumerate(("smoothness", "splay_deg"))
                         if name in self.priors))

    def fix_specular(self, x: NDArray[np.float64], ks: float) -> NDArray[np.float64]:
        """Stop fitting ``ks``: hold it at ``ks`` from now on; returns ``x`` without it."""
        self.fit_ks, self.fixed_ks = False, float(ks)
        self.lower, self.upper, self.x0 = self.lower[:-1], self.upper[:-1], self.x0[:-1]
        return x[:-1]

    def unpack(self, x: NDArray[np.float64]) -> tuple[NDArray[np.float64], float]:
        """(4, 3) linear albedos and ``ks`` of parameter vector ``x``."""
        albedo = self.base_albedo.copy()
        for i, p in enumerate(self.albedo_params):
            albedo[ALBEDO_ROWS[p]] = srgb_to_linear(x[3 * i: 3 * i + 3])
        ks = float(x[-1]) if self.fit_ks else self.fixed_ks
        return albedo, ks

    def weights(self, shape: tuple[float, float], x: NDArray[np.float64] | None = None) -> None:
        """Per fitted series and CIELAB component, the residuals' standard deviation at
        parameters ``x`` (default: the start): the layouts' spread (the real pixel is one more
        layout), the Monte Carlo error of the layout mean, and the photos' floor, pooled over
        the series' lengths."""
        albedo, ks = self.unpack(self.x0 if x is None else x)
        floor = self.model.settings.lab_floor
        for s in self.fit_series:
            reps = self.model.replicates(shape, s, albedo, ks)  # (L, R, n, 3)
            n_layouts, n_reps = reps.shape[:2]
            spread = self.model.lab(reps.mean(axis=1)).var(axis=0, ddof=1)  # (n, 3)
            # The layout means' spread holds their own Monte Carlo error: take it out (the
            # replicates' spread within a layout) to leave the layouts' own.
            mc = (self.model.lab(reps).var(axis=1, ddof=1).mean(axis=0) / n_reps
                  if n_reps > 1 else np.zeros_like(spread))
            layout = np.clip(spread - mc, 0.0, None)
            self.sigma[s] = np.sqrt((layout + spread / n_layouts).mean(axis=0) + floor ** 2)

    def residuals(self, shape: tuple[float, float], x: NDArray[np.float64]
                  ) -> NDArray[np.float64]:
        """Whitened CIELAB residuals (real - simulated) of every fitted photo."""
        albedo, ks = self.unpack(x)
        out = []
        for s in self.fit_series:
            mean = self.model.mean(shape, s, albedo, ks)
            out.append(((self.real.lab[s] - self.model.lab(mean)) / self.sigma[s]).ravel())
        return np.concatenate([*out, self.prior_rows(x)])

    def solve(self, shape: tuple[float, float], x0: NDArray[np.float64] | None = None) -> _Inner:
        """Least squares of the albedos / ``ks`` at one shape (Gauss-Newton, trust region)."""
        from scipy.optimize import least_squares

        if not self.sigma:
            self.weights(shape)
        start = np.clip(self.x0 if x0 is None else x0, self.lower, self.upper)
        prior = self.shape_prior(shape)
        if not len(start):
            r = self.residuals(shape, start)
            return _Inner(start, r, np.zeros((len(r), 0)), float(r @ r) + prior,
                          self.noise(shape, start))
        res = least_squares(lambda x: self.residuals(shape, x), start,
                            bounds=(self.lower, self.upper), x_scale="jac", max_nfev=200)
        if res.status <= 0:
            raise FitNotConvergedError(
                f"the albedo fit did not converge in {res.nfev} evaluations ({res.message}); "
                "check that the photos show the pixel named in the manifest")
        return _Inner(res.x, res.fun, res.jac, float(res.fun @ res.fun) + prior,
                      self.noise(shape, res.x))

    def noise(self, shape: tuple[float, float], x: NDArray[np.float64]) -> float:
        """Expected chi-square contribution of the simulation's Monte Carlo noise at ``x``: per
        photo and CIELAB component, the variance of the simulated mean (the replicates'
        spread within each layout, over all replicates) over the residual's variance."""
        albedo, ks = self.unpack(x)
        total = 0.0
        for s in self.fit_series:
            reps = self.model.replicates(shape, s, albedo, ks)  # (L, R, n, 3)
            n_layouts, n_reps = reps.shape[:2]
            if n_reps < 2:
                continue
            within = self.model.lab(reps).var(axis=1, ddof=1).mean(axis=0)
            total += float((within / (n_layouts * n_reps) / self.sigma[s] ** 2).sum())
        return total

    def layout_jackknife(self, shape: tuple[float, float], x: NDArray[np.float64]
                         ) -> NDArray[np.float64]:
        """Covariance of the fitted albedos / ``ks`` that the photographed layout's accident
        causes: each simulated layout in turn stands in for the photographed pixel (its own
        mean at ``x``) and is fitted with the mean of the other layouts; the covariance of
        those fits (ddof 1). Costs one small least-squares fit per layout (milliseconds)."""
        from scipy.optimize import least_squares

        albedo, ks = self.unpack(x)
        reps = {s: self.model.replicates(shape, s, albedo, ks) for s in self.fit_series}
        n_layouts = next(iter(reps.values())).shape[0]
        fits = []
        for k in range(n_layouts):
            target = {s: self.model.lab(r[k].mean(axis=0)) for s, r in reps.items()}
            others = [j for j in range(n_layouts) if j != k]

            def resid(y: NDArray[np.float64], target=target, others=others) -> NDArray:
                a, k_s = self.unpack(y)
                out = []
                for s in self.fit_series:
                    sim = self.model.mean(shape, s, a, k_s, others)
                    out.append(((target[s] - self.model.lab(sim)) / self.sigma[s]).ravel())
                return np.concatenate([*out, self.prior_rows(y)])

            fits.append(least_squares(resid, x, bounds=(self.lower, self.upper),
                                      x_scale="jac", max_nfev=100).x)
        return np.atleast_2d(np.cov(np.array(fits), rowvar=False, ddof=1))


def _next_candidate(points: Sequence[tuple[float, float]], lo: float, hi: float) -> float:
    """The next value to try in a profile of the misfit: where the lowest point lies inside
    the values tried, the vertex of the parabola through it and its two neighbours (kept
    between them; the lowest point itself where that parabola is not convex); where it lies at
    an end short of ``lo`` / ``hi``, one spacing further out (the minimum is not bracketed).

    >>> _next_candidate([(0.0, 4.0), (1.0, 1.0), (2.0, 2.0)], 0.0, 3.0)
    1.25
    >>> _next_candidate([(0.0, 4.0), (1.0, 2.0), (2.0, 1.0)], 0.0, 3.0)
    3.0
    """
    pts = sorted(points)
    i = min(range(len(pts)), key=lambda k: pts[k][1])
    if len(pts) < 3:
        return pts[i][0]
    if i in (0, len(pts) - 1):
        j = 1 if i == 0 else len(pts) - 2
        step = pts[i][0] - pts[j][0]
        out = float(np.clip(pts[i][0] + step, lo, hi))
        if out != pts[i][0]:
            return out
        i = j  # at lo / hi: the vertex of the three nearest, clipped to lo / hi
    (xa, ya), (xb, yb), (xc, yc) = pts[i - 1: i + 2]
    a, b, _ = np.polyfit([xa, xb, xc], [ya, yb, yc], 2)
    if a <= 0:
        return pts[min(range(len(pts)), key=lambda k: pts[k][1])][0]
    lowest = min(pts, key=lambda p: p[1])[0]
    span = (xa, xc) if lowest not in (pts[0][0], pts[-1][0]) else (lo, hi)
    return round(float(np.clip(-b / (2 * a), *span)), 4)


def _profile_stderr(points: Sequence[tuple[float, float]], rise: float) -> float | None:
    """Standard error of a re-rendered parameter from the profile of the misfit: the distance
    from the lowest point to where the profile rises by ``rise`` (1 for a chi-square, more
    where the residuals are wider than their weights), interpolated linearly between the
    points tried, on each side that reaches it (their mean where both do; one side at the
    edge of the grid). None where no side reaches it: the photos do not determine it.

    >>> _profile_stderr([(0, 4.0), (4, 0.0), (8, 4.0)], 1.0)
    1.0
    """
    pts = sorted(points)
    i = min(range(len(pts)), key=lambda k: pts[k][1])
    x0, y0 = pts[i]
    widths = []
    target = y0 + rise
    for side in (pts[i::-1], pts[i:]):  # outward from the lowest point
        for (xa, ya), (xb, yb) in zip(side, side[1:], strict=False):
            if yb >= target:  # the previous point is below the target
                widths.append(abs(xa + (xb - xa) * (target - ya) / (yb - ya) - x0))
                break
    return float(np.mean(widths)) if widths else None


def _covariance(inner: _Inner, dof: int) -> NDArray[np.float64]:
    """Gauss-Newton covariance ``(J^T J)^-1`` of the whitened fit, scaled by the reduced
    chi-square where it exceeds 1 (the residuals are then wider than their weights say).
    Raises :class:`numpy.linalg.LinAlgError` when the parameters are not determined."""
    jtj = inner.jac.T @ inner.jac
    if np.linalg.cond(jtj) > 1e12:
        raise np.linalg.LinAlgError("singular")
    return np.linalg.inv(jtj) * max(1.0, inner.cost / max(dof, 1))


def unseen_parameters(manifest: CaptureManifest, fit_series: Sequence[int],
                      params: Sequence[str], start: PixelSpec) -> dict[str, str]:
    """The fitted parameters these photos cannot show at all, each with why and what to
    photograph: the splay without long green blades, the glossy lobe (``specular``,
    ``smoothness``) from one viewpoint. The fit holds them at their prior from the start.

    Raises:
        NotIdentifiableError: no viewpoint is left to fit (every one held out).
    """
    if not fit_series:
        raise NotIdentifiableError("every viewpoint is held out: keep at least one for fitting "
                                   "(--holdout names the ones to judge with only)")
    unseen: dict[str, str] = {}
    longest = max(float(manifest.series[s].lengths_mm.max()) for s in fit_series)
    need = SPLAY_MIN_LENGTH_FRACTION * start.green_max_mm
    if "splay_deg" in params and longest < need:
        unseen["splay_deg"] = (
            f"splay shows on long blades and the longest green length photographed is "
            f"{longest:g} mm; photograph lengths up to at least {need:g} mm to fit it")
    views = {manifest.series[s].viewpoint for s in fit_series}
    for p in ("specular", "smoothness"):
        if p in params and len(views) < 2:
            unseen[p] = (f"{p} cannot be seen from one viewpoint: a glossy lobe is told from the "
                         f"albedos only by how the colour changes with the view; photograph at "
                         f"least 2 viewpoints (not held out) to fit it")
    return unseen


def _match_holdout(manifest: CaptureManifest, holdout: Sequence[tuple[float, float, float]]
                   ) -> set[int]:
    out = set()
    for vp in holdout:
        hits = [i for i, s in enumerate(manifest.series)
                if np.allclose(s.viewpoint, vp, atol=1e-6)]
        if not hits:
            have = ", ".join(s.label for s in manifest.series)
            raise FitError(f"--holdout {vp[0]:g},{vp[1]:g},{vp[2]:g} is not a viewpoint of the "
                           f"capture (it has {have})")
        out.update(hits)
    return out


def _lobe_hidden(ks: float, ks_se: float) -> bool:
    """Whether a fitted specular ``ks`` (with standard error ``ks_se``) shows no glossy lobe
    whose shape the photos could tell."""
    return ks < max(MIN_VISIBLE_SPECULAR, 3.0 * ks_se)


class _ShapeSearch:
    """The lobe's shape and the splay, searched over the albedo fit (:meth:`_Problem.solve`):
    ``shape`` (smoothness, splay_deg) and ``best`` (the fit there) so far, and for every
    parameter searched, each candidate's misfit (``profile``) and fitted x (``along``)."""

    def __init__(self, problem: _Problem, shape: tuple[float, float], best: _Inner,
                 say: Callable[[str], None]) -> None:
        self.problem = problem
        self.shape = shape
        self.best = best
        self.say = say
        self.profile: dict[str, list[tuple[float, float]]] = {}
        self.along: dict[str, dict[float, NDArray[np.float64]]] = {}

    def search(self, name: str, grid: Sequence[float], index: int, lo: float, hi: float,
               refine: int) -> None:
        """Fit at every ``grid`` value of shape entry ``index`` (``name``), then up to
        ``refine`` successive parabolic steps kept in [``lo``, ``hi``]; the best becomes
        ``shape`` and ``best`` (FitNotConvergedError when no candidate converged)."""
        tried: dict[float, _Inner | None] = {}

        def attempt(v: float, what: str) -> None:
            cand = (v, self.shape[1]) if index == 0 else (self.shape[0], v)
            self.say(f"recording {name} = {v:.3g}{what}")
            try:
                tried[v] = self.problem.solve(cand, self.best.x)
            except FitNotConvergedError:  # a far-off candidate: out of the running
                tried[v] = None

        for v in grid:
            attempt(float(v), "")
        for _ in range(refine):  # successive parabolic interpolation, kept in its bracket
            points = [(v, r.misfit) for v, r in tried.items() if r is not None]
            if not points:
                break
            v_next = _next_candidate(points, lo, hi)
            if min(abs(v_next - v) for v in tried) < REFINE_TOLERANCE[name]:
                break
            attempt(v_next, " (refined)")
        ok = {v: r for v, r in tried.items() if r is not None}
        if not ok:
            raise FitNotConvergedError(f"the albedo fit converged at no {name} tried "
                                       f"({', '.join(f'{v:g}' for v in grid)}); check that "
                                       "the photos show the pixel named in the manifest")
        v_best = min(ok, key=lambda v: ok[v].misfit)
        self.shape = (v_best, self.shape[1]) if index == 0 else (self.shape[0], v_best)
        self.best = ok[v_best]
        self.profile[name] = sorted((v, r.misfit) for v, r in ok.items())
        self.along[name] = {v: r.x for v, r in ok.items()}

    def specular_error(self) -> tuple[float, float]:
        """The fitted ``ks`` and its standard error at the current shape."""
        best = self.best
        try:
            cov = (_covariance(best, best.residuals.size - best.x.size)
                   + self.problem.layout_jackknife(self.shape, best.x))
        except np.linalg.LinAlgError:
            raise NotIdentifiableError(
                "the photos do not determine specular together with the albedos (singular "
                "fit); add viewpoints or leave specular and smoothness out of --params",
                "specular") from None
        return self.problem.unpack(best.x)[1], float(np.sqrt(cov[-1, -1]))


def fit_capture(manifest: CaptureManifest, *, holdout: Sequence[tuple[float, float, float]] = (),
                params: Sequence[str] = FIT_PARAMS, settings: FitSettings | None = None,
                renderer: Renderer | None = None, lighting: Lighting | None = None,
                arch: str = "cpu", progress: Callable[[str], None] | None = None) -> FitResult:
    """Fit the pixel's materials to a capture (see the module docstring).

    ``holdout``: viewpoints (h cm, d m, theta deg) judged but not fitted; ``params``: the
    fitted fields (the rest stay as the manifest's ``[pixel]`` says); ``renderer`` /
    ``lighting``: prebuilt ones (else built here on ``arch``). Raises :class:`FitError`
    subclasses naming what to change.
    """
    from grassd.sim.scene import PixelSpec

    t0 = time.perf_counter()
    settings = settings or FitSettings()
    say = progress or (lambda _m: None)
    unknown = sorted(set(params) - set(FIT_PARAMS))
    if unknown:
        raise FitError(f"unknown parameter(s) {', '.join(unknown)}; choose from "
                       f"{', '.join(FIT_PARAMS)}")
    params = tuple(p for p in FIT_PARAMS if p in params)
    start = PixelSpec(**manifest.pixel)
    held = _match_holdout(manifest, holdout)
    fit_series = [i for i in range(len(manifest.series)) if i not in held]
    priors = unseen_parameters(manifest, fit_series, params, start)  # parameter -> why
    if params and all(p in priors for p in params):
        raise NotIdentifiableError(
            "these photos determine none of " + ", ".join(params) + ": "
            + "; ".join(priors.values()), next(iter(priors), None))
    chart = get_chart(manifest.chart)
    real, correction, scale = measure_and_correct(manifest, chart, progress)
    say("building the lighting")
    lighting = lighting if lighting is not None else manifest.light.lighting()
    chain = simulation_chain(manifest.sensitivities, correction, scale,
                             lighting, real.white_balance,
                             manifest.checker_photo, chart)
    renderer = renderer if renderer is not None else default_renderer(arch)
    glossy = "specular" in params or start.specular > 0
    model = _Model(renderer, lighting, manifest, chain, start, settings, glossy)
    model.fit_series = fit_series
    while True:
        try:
            fitted = _fit(model, real, manifest, fit_series, held, params, priors, say)
            break
        except NotIdentifiableError as exc:
            p = exc.parameter
            if p is None or p in priors:
                raise
            if not [q for q in params if q != p and q not in priors]:
                raise NotIdentifiableError(
                    f"the photos determine none of {', '.join(params)}: {exc}", p) from None
            priors[p] = str(exc)
            say(f"{p} is not determined by the photos: held at its prior, fitting the rest")
    held_notes = tuple(
        f"{p} held at its prior, the [pixel] value {_prior_text(start, p)} +- "
        f"{PRIOR_STDERR[p]:g}, while the rest was fitted: {why}"
        for p, why in priors.items())
    return replace(fitted, notes=held_notes + fitted.notes, seconds=time.perf_counter() - t0)


def _prior_text(start: PixelSpec, p: str) -> str:
    """A ``[pixel]`` field's value as the notes print it."""
    v = getattr(start, p)
    return f"({', '.join(f'{c:g}' for c in v)})" if isinstance(v, tuple) else f"{v:g}"


def _fit(model: _Model, real: RealCapture, manifest: CaptureManifest, fit_series: list[int],
         held: set[int], params: tuple[str, ...], priors: dict[str, str],
         say: Callable[[str], None]) -> FitResult:
    """One fit of ``params`` with those named in ``priors`` held at their prior
    (:data:`PRIOR_STDERR`); :func:`fit_capture` without its checks and set-up."""
    t0 = time.perf_counter()
    start, settings = model.start, model.settings
    problem = _Problem(model, real, fit_series, params)
    problem.priors = set(priors)
    notes: list[str] = []
    shape = (start.smoothness, start.splay_deg)
    say(f"fitting albedos at smoothness {shape[0]:g}, splay {shape[1]:g} deg")
    best = problem.solve(shape)
    if len(best.x):  # the layouts' spread in CIELAB depends on the colours: weigh at the fit's
        problem.weights(shape, best.x)
        best = problem.solve(shape, best.x)
    look = _ShapeSearch(problem, shape, best, say)
    shape, best, kept, specular_se = _fit_shape(problem, look, start, params, notes)
    profile = look.profile
    n_par = len(best.x) + sum(1 for p in ("splay_deg", "smoothness")
                              if p in profile and p not in kept)
    dof = max(len(best.residuals) - n_par, 1)
    albedo, ks = problem.unpack(best.x)
    _check_agreement(model, real, fit_series, shape, albedo, ks)
    pixel, stderr, given_shape = _fitted_fields(problem, best, shape, params, dof, profile,
                                                kept, look.along)
    if "specular" in kept:
        pixel["specular"], stderr["specular"] = 0.0, round(specular_se, 4)
        pixel = {k: pixel[k] for k in FIT_PARAMS if k in pixel}  # report order
        stderr = {k: stderr[k] for k in FIT_PARAMS if k in stderr}
    # What the photos do not determine even at the fitted shape is refused; what is uncertain
    # through the shape's uncertainty is reported, with a note.
    for p in priors:  # at least as well known as its prior says, whatever the profile showed
        if stderr.get(p) is None:
            stderr[p] = [PRIOR_STDERR[p]] * 3 if p in ALBEDO_ROWS else PRIOR_STDERR[p]
    _check_determined({**stderr, **given_shape}, params, kept | set(priors), profile)
    for p, v in given_shape.items():
        se = stderr[p]
        worst = max(se) if isinstance(se, list) else se
        if worst is not None and worst > MAX_STDERR[p]:
            notes.append(f"{p}'s standard error is up to {worst:.3g} ("
                         f"{max(v) if isinstance(v, list) else v:.3g} if the splay and "
                         "smoothness were exact): it follows the lobe's shape or the splay, "
                         "which the photos pin down loosely; more viewpoints (steep ones for "
                         "the base) narrow it")
    say("judging every viewpoint")
    start_shape = (start.smoothness, start.splay_deg)
    start_albedo, _ = problem.unpack(problem.x0)
    judged = tuple(
        ViewpointFit(i, sr.viewpoint, i in held,
                     _judge(model, real, i, start_shape, start_albedo, start.specular),
                     _judge(model, real, i, shape, albedo, ks))
        for i, sr in enumerate(manifest.series))
    start_fields = {k: (list(v) if isinstance(v, tuple) else v)
                    for k, v in asdict(start).items()}
    return FitResult(pixel=pixel, stderr=stderr, start=start_fields, viewpoints=judged,
                     chi2=best.cost, dof=dof, seconds=time.perf_counter() - t0,
                     settings=settings, notes=tuple(notes), profile=profile,
                     chain=model.chain.form)


def _fit_shape(problem: _Problem, look: _ShapeSearch, start: PixelSpec,
               params: tuple[str, ...], notes: list[str]
               ) -> tuple[tuple[float, float], _Inner, set[str], float]:
    """The lobe's shape and the splay searched (``look``, from the fit at the start's shape)
    where ``params`` fit them: the shape (smoothness, splay_deg), the fit there, the fitted
    parameters the photos could not show (kept at the start, each said in ``notes``), and the
    standard error of a fitted specular set to 0 (0 otherwise)."""
    # The lobe's shape first, coarsely (a sharp lobe fitted with a broad one's shape looks like
    # no gloss at all), then the splay at that shape, then the shape again, finely, at that
    # splay: the hidden base's colour follows the lobe's shape closely (the olive pixel's blue
    # moves about 3 levels per 0.01 of smoothness), so the shape's minimum is refined to
    # REFINE_TOLERANCE rather than read off a coarse grid.
    glossy_fit = "smoothness" in params and (problem.fit_ks or start.specular > 0)
    kept: set[str] = set()  # fitted parameters the photos could not show: kept at the start
    specular_se = 0.0  # of a fitted specular set to 0
    if "smoothness" in params and not glossy_fit:
        kept.add("smoothness")
        notes.append(f"smoothness kept at {start.smoothness:g}: without a glossy lobe (specular 0, "
                     "not fitted) its shape does not show")
    splay_fit = "splay_deg" in params
    if glossy_fit:
        # Coarse only where the splay follows: the fine pass then starts at its best.
        look.search("smoothness", SMOOTHNESS_GRID, 0, 0.0, 0.97, 0 if splay_fit else MAX_REFINE)
    if splay_fit:
        look.search("splay_deg", SPLAY_GRID, 1, 0.0, 30.0, MAX_REFINE)
        if glossy_fit and not (problem.fit_ks and _lobe_hidden(*look.specular_error())):
            s0 = look.shape[0]
            local = sorted({float(np.clip(s0 + d, 0.0, 0.97))
                            for d in (-SMOOTHNESS_STEP, 0.0, SMOOTHNESS_STEP)})
            look.search("smoothness", local, 0, 0.0, 0.97, MAX_REFINE)
    shape, best = look.shape, look.best
    if glossy_fit and problem.fit_ks:
        ks, ks_se = look.specular_error()
        if _lobe_hidden(ks, ks_se):
            # No lobe to speak of: its shape is noise. Keep the start's, refitted there.
            notes.append(f"smoothness kept at {start.smoothness:g}: the fitted specular "
                         f"({ks:.3f} +- {ks_se:.3f}) shows no glossy lobe whose shape the "
                         "photos could tell")
            shape = (start.smoothness, shape[1])
            kept.add("smoothness")
            if ks < max(MIN_VISIBLE_SPECULAR, 2.0 * ks_se):
                # Within 2 standard errors of none: the simpler pixel, without a lobe.
                notes.append(f"specular set to 0: the fitted {ks:.3f} +- {ks_se:.3f} is within "
                             "2 standard errors of no gloss")
                kept.add("specular")
                specular_se = ks_se
                best = problem.solve(shape, problem.fix_specular(best.x, 0.0))
            else:
                best = problem.solve(shape, best.x)
    return shape, best, kept, specular_se


def _fitted_fields(problem: _Problem, best: _Inner, shape: tuple[float, float],
                   params: Sequence[str], dof: int,
                   profile: dict[str, list[tuple[float, float]]],
                   kept: set[str], along: dict[str, dict[float, NDArray[np.float64]]]
                   ) -> tuple[dict[str, float | list[float]],
                              dict[str, float | list[float] | None],
                              dict[str, float | list[float]]]:
    """The fitted fields by their config names, their standard errors (module docstring;
    None where a parameter was kept at its start or its profile never rises enough), and the
    albedos' and specular's standard errors at the fitted splay and smoothness (without their
    uncertainty). ``along``: per re-rendered parameter, the fitted parameter vector at each
    value tried, whose slope carries that parameter's uncertainty into the albedos' and
    specular's."""
    pixel: dict[str, float | list[float]] = {}
    stderr: dict[str, float | list[float] | None] = {}
    cov = np.zeros((0, 0))
    design = 1.0  # how much the shared layout accident inflates a variance
    if len(best.x):
        try:
            gauss_newton = _covariance(best, dof)
            cov = gauss_newton + problem.layout_jackknife(shape, best.x)
            design = float(np.mean(np.diag(cov) / np.diag(gauss_newton)))
        except np.linalg.LinAlgError:
            weakest = problem.albedo_params + (["specular"] if problem.fit_ks else [])
            raise NotIdentifiableError(
                f"the photos do not determine {', '.join(weakest)} together (singular fit); "
                "add lengths or viewpoints, or fit fewer parameters with --params") from None
    # The profile's rise: 1 for a chi-square, more where the residuals are wider than their
    # weights, times the albedos' inflation by the layout accident (which splay and smoothness
    # share, but whose jackknife would need every layout recorded at every candidate).
    rise = max(1.0, best.cost / dof) * design
    given = np.sqrt(np.diag(cov))
    shape_fields: dict[str, float | list[float]] = {}
    shape_se: dict[str, float | list[float] | None] = {}
    for name, index in (("smoothness", 0), ("splay_deg", 1)):
        if name in params:
            shape_fields[name] = round(float(shape[index]), 3)
            width = (None if name in kept or name not in profile
                     else _profile_stderr(profile[name], rise))
            shape_se[name] = None if width is None else round(width, 3)
            slope = (None if width is None or len(best.x) == 0 or name not in along
                     else _slope(along[name], float(shape[index]), len(best.x)))
            if slope is not None:  # the albedos move with it
                cov = cov + np.outer(slope, slope) * width ** 2
    se = np.sqrt(np.diag(cov))
    given_shape: dict[str, float | list[float]] = {}
    for i, p in enumerate(problem.albedo_params):
        pixel[p] = [round(float(v), 2) for v in best.x[3 * i: 3 * i + 3]]
        stderr[p] = [round(float(v), 2) for v in se[3 * i: 3 * i + 3]]
        given_shape[p] = [round(float(v), 2) for v in given[3 * i: 3 * i + 3]]
    if problem.fit_ks:
        pixel["specular"] = round(problem.unpack(best.x)[1], 4)
        stderr["specular"] = round(float(se[-1]), 4)
        given_shape["specular"] = round(float(given[-1]), 4)
    return {**pixel, **shape_fields}, {**stderr, **shape_se}, given_shape


def _slope(points: dict[float, NDArray[np.float64]], at: float, size: int
           ) -> NDArray[np.float64] | None:
    """The slope of the fitted parameter vector along a profile at ``at``: the difference of
    the fits tried nearest below and above it (one side and ``at`` itself at the edge of
    what was tried), the first ``size`` entries (a specular set to 0 later drops the last);
    None where only ``at`` was tried.

    >>> _slope({0.0: np.array([1.0]), 0.5: np.array([2.0]), 1.0: np.array([4.0])}, 0.5, 1).tolist()
    [3.0]
    """
    below = [v for v in points if v < at]
    above = [v for v in points if v > at]
    lo = max(below) if below else at
    hi = min(above) if above else at
    if hi == lo or lo not in points or hi not in points:
        return None
    return (points[hi][:size] - points[lo][:size]) / (hi - lo)


def _check_agreement(model: _Model, real: RealCapture, fit_series: Sequence[int],
                     shape: tuple[float, float], albedo: NDArray[np.float64], ks: float) -> None:
    """Refuse photos that no materials reconcile: the fitted model should reach every photo
    within the layout noise (checked before any standard error, which their misfit would
    inflate)."""
    de = []
    for i in fit_series:
        mean = model.mean(shape, i, albedo, ks)
        de.extend(zip(delta_E(real.lab[i], model.lab(mean), method="CIE 2000"),
                      [p.path.name for p in model.manifest.series[i].photos], strict=True))
    median = float(np.median([d for d, _ in de]))
    if median > CONTRADICTION_DE00:
        worst_de, worst_name = max(de)
        raise ContradictoryPhotosError(
            f"no materials make the simulation agree with the photos: after fitting they still "
            f"differ by a median {median:.1f} dE00 (worst {worst_name}, {worst_de:.1f}); check "
            "that every photo shows the same pixel under the light in the manifest, with the "
            "checker taken at the same time")


def _check_determined(stderr: dict[str, float | list[float] | None], params: Sequence[str],
                      kept: set[str], profile: dict[str, list[tuple[float, float]]]) -> None:
    """Refuse, naming it, a fitted parameter whose standard error exceeds its limit."""
    for p, limit in MAX_STDERR.items():
        v = stderr.get(p)
        worst = max(v) if isinstance(v, list) else v
        if p in params and p not in kept and (worst is None or worst > limit):
            tried = "".join(f"; misfit (chi2) by {p}: " + ", ".join(
                f"{v:g}: {c:.1f}" for v, c in profile[p]) if p in profile else "")
            raise NotIdentifiableError(
                f"the photos do not determine {p} (standard error "
                f"{'unbounded' if worst is None else f'{worst:.3g}'}, limit {limit:g}{tried}); "
                "photograph more lengths or viewpoints, or leave it out of --params", p)


def _judge(model: _Model, real: RealCapture, series: int, shape: tuple[float, float],
           albedo: NDArray[np.float64], ks: float) -> ViewpointComparison:
    """A series' real characteristic against the model's (every layout's replicates)."""
    sr = model.manifest.series[series]
    reps = model.replicates(shape, series, albedo, ks)
    x = reps.reshape(-1, *reps.shape[2:])
    res = model.chain.ogcd(x)
    return compare_viewpoint(sr.viewpoint, sr.lengths_mm, real.ogcd[series], res.ogcd,
                             sim_stderr=res.ogcd_stderr, real_lab=real.lab[series],
                             sim_lab=res.lab)


def load_pixel_fields(path: str | Path) -> dict[str, PixelValue]:
    """PixelSpec fields from a ``grassd fit`` result: its JSON report (the start with the
    fitted fields over it) or a TOML file holding a ``[display.pixel]`` table (what
    ``--toml`` writes, or a whole grassd.toml) or a ``[pixel]`` table. Raises
    :class:`FitError` for another file, an unknown field or one that is neither a number nor
    a list of numbers."""
    import json
    import tomllib

    from grassd.sim.scene import PixelSpec

    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except OSError as exc:
        raise FitError(f"cannot read the fitted pixel {p}: {exc.strerror}") from None
    try:
        if p.suffix == ".json":
            data = json.loads(text)
            fields = {**data["start"], **data["pixel"]}
        else:
            data = tomllib.loads(text)
            fields = data.get("display", {}).get("pixel", data.get("pixel"))
            if fields is None:
                raise KeyError("pixel")
    except (ValueError, KeyError, TypeError, AttributeError):
        raise FitError(f"{p} holds no fitted pixel: give the JSON report of grassd fit or a "
                       "TOML file with a [display.pixel] table") from None
    unknown = sorted(set(fields) - set(PixelSpec.__dataclass_fields__))
    if unknown:
        raise FitError(f"{p}: unknown pixel field(s) {', '.join(unknown)}")
    out: dict[str, PixelValue] = {}
    for k, v in fields.items():
        value = tuple(v) if isinstance(v, list) else v
        numbers = value if isinstance(value, tuple) else (value,)
        if not all(isinstance(x, int | float) and not isinstance(x, bool) for x in numbers):
            raise FitError(f"{p}: pixel field {k} must be a number or a list of numbers, "
                           f"got {v!r}")
        out[k] = value
    return out
