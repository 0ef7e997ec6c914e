"""One measurement of the display, from test patterns to a verdict (``grassd measure``).

1. **The tables without correction**: a calibration run for the light now, as any run, but with
   no display correction (:meth:`Calibrator.run <grassd.daemon.core.calibration.calibrate.Calibrator
   .run>`, ``correction=None``).
2. **Photos under test patterns** (:class:`~grassd.daemon.measure.patterns.PatternSession`):
   every pixel at its shortest and longest grass (the difference finds the display), at
   ``[measure] patterns`` lengths (the pixels' characteristics), and at :data:`CHECK_LEVELS`
   through the uncorrected tables (uniformity before), in an order drawn at random for this
   measurement, one state photographed twice (:func:`~grassd.daemon.measure.evidence.shot_order`).
   The lux is read at every shot; light that changes by more than ``steady_lux`` ends the
   measurement.
3. (The display shows content while the photos are analysed: steps 3 to 5 take a minute or
   two.) **Where the camera stands**: the display located in the photos and the pose solved from its
   known size (:mod:`grassd.calib.display_in_photo`); that pose is the viewpoint the photos stand
   for. Each pixel's mean colour through the camera's chain
   (:mod:`grassd.daemon.measure.camera_chain`) to CIELAB.
4. **Each pixel's departure** (:func:`~grassd.daemon.measure.pixel_model.fit_variation`):
   length offset, green and yellow gain, fitted to its colours against the model pixel recorded
   at its own viewpoint from the camera.
5. **The correction** carried to the configured viewers
   (:func:`~grassd.daemon.measure.pixel_model.corrected_commands`) and the tables with it.
6. **Verification**: the corrected tables' levels shown as patterns again and photographed
   (uniformity after).
7. Patterns end: the display shows content again, whatever happened before. Only a measurement
   that got this far, whose photos are evidence (fresh, each of its state, the fit and the
   verification within the measurement's noise: :mod:`grassd.daemon.measure.evidence`) and
   whose correction makes the display more uniform, is kept: its correction saved and its
   tables committed and pushed as a run (trigger "measure"). Nothing from a measurement that
   was refused, failed or was interrupted is pushed; the last good tables stay.

The whole measurement has a deadline (``[measure] deadline_s``), checked at every step and while
each shot is taken: past it, the display shows content again and :class:`MeasureDeadline` ends
the run.

**Uniformity** (the report's ``uniformity``): at each checked level, every pixel's measured
colour with its viewing geometry divided out (measured / model pixel at its own viewpoint, times
the display's mean model colour, in linear ProPhoto), so that what remains is how the pixels
differ, not where the camera stands. ``worst_pair``: the largest CIEDE2000 between two pixels at
the mid level (128); ``ogcd_spread``: per level, the standard deviation across pixels of the
OGCD (each pixel's difference from its own level-0 colour).

Units: lengths mm, colours CIELAB (D50), differences CIEDE2000, lux, seconds.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING, TypeVar

import numpy as np
from colour import delta_E
from numpy.typing import NDArray

from grassd.daemon.core.errors import DaemonError, RunInterrupted
from grassd.daemon.measure.evidence import Evidence, Finding, PhotosRefused, Refusal
from grassd.daemon.measure.report import MeasurementReport, Uniformity

if TYPE_CHECKING:
    from grassd.calib.display_in_photo import DisplayInPhoto
    from grassd.daemon.camera.client import OscClient
    from grassd.daemon.core.calibration.calibrate import Calibrates
    from grassd.daemon.core.calibration.correction import DisplayCorrection
    from grassd.daemon.core.calibration.result import CalibrationResult
    from grassd.daemon.core.calibration.transport import SpectralTransport
    from grassd.daemon.core.calibration.variation import DisplayVariation
    from grassd.daemon.core.config.settings import Config, ViewpointConfig
    from grassd.daemon.core.hardware.fleet import Fleet
    from grassd.daemon.measure.camera_chain import MeasureSetup, Shot
    from grassd.daemon.measure.pixel_model import PixelColourModel, VariationFit
    from grassd.sim.light_input import LightInput
    from grassd.sim.lighting import Lighting
    from grassd.sim.renderer import Renderer
    from grassd.sim.scene import DisplaySpec, RenderSettings

T = TypeVar("T")

log = logging.getLogger(__name__)

#: Levels photographed through the tables before and after the correction (the mid level,
#: 128, gives the worst pixel pair).
CHECK_LEVELS: tuple[int, ...] = (0, 64, 128, 192, 255)
MID_LEVEL: int = 128
#: Spacing of the pixel models' length grid (mm).
GRID_STEP_MM: float = 0.5


class MeasureError(DaemonError):
    """A measurement failed; the last good tables stay active (the message says why)."""


class UnsteadyLight(MeasureError):
    """The light changed too much while the display was photographed."""


@dataclass
class Photos:
    """Each pixel's mean developed colour (linear ProPhoto, normalised) per shot name."""

    rgb: dict[str, NDArray[np.float64]] = field(default_factory=dict)
    lux: list[float] = field(default_factory=list)


@dataclass(frozen=True)
class MeasureContext:
    """What a measurement uses of the daemon: its config, fleet, calibrator, the light now
    (``light``, a LightInput; ``lux()`` reads the sensor, or the manifest's lux), the
    measuring camera's client and set-up, where its files go (``dest``), ``stop()`` and
    ``progress(text)``."""

    cfg: Config
    fleet: Fleet
    calibrator: Calibrates
    light: LightInput
    lux: Callable[[], float]
    camera: OscClient
    setup: MeasureSetup
    dest: Path
    stop: Callable[[], bool]
    progress: Callable[[str], None]


@dataclass(frozen=True)
class Analysis:
    """What the photos before the correction gave (steps 3 to 5 of the module docstring): the
    display ``located`` in them (its camera pose too), every pixel's CIELAB at the patterns
    (``measured_lab``, (N, K, 3)) and its normalised ProPhoto at :data:`CHECK_LEVELS` before
    the correction (``before``, (N, L, 3)), the pixel model recorded from the camera and its
    ``fit``, the ``correction``, the camera's ``ccm`` (3 x 3), each checked level's nominal
    lengths (mm, (N,) by level) and the photos' ``evidence``."""

    located: DisplayInPhoto
    measured_lab: NDArray[np.float64]
    before: NDArray[np.float64]
    camera_model: PixelColourModel
    fit: VariationFit
    correction: DisplayCorrection
    ccm: NDArray[np.float64]
    nominal_lengths: dict[int, NDArray[np.float64]]
    evidence: Evidence


@dataclass(frozen=True)
class MeasurementOutcome:
    """How a measurement ended: its ``report`` (JSON-ready, written by
    :mod:`grassd.daemon.measure.report`) and, when it was accepted, the correction and the
    corrected tables to keep (None: refused, the report's ``evidence`` and ``status`` say
    why)."""

    report: MeasurementReport
    accepted: tuple[DisplayCorrection, CalibrationResult] | None


def measurement_id(at: datetime | None = None) -> str:
    """A measurement's id: its UTC start, ``YYYYmmddTHHMMSSZ`` (report file stem)."""
    return (at or datetime.now(UTC)).strftime("%Y%m%dT%H%M%SZ")


def pattern_lengths(count: int, green_max_mm: float) -> NDArray[np.float64]:
    """``count`` lengths (mm) evenly over the range, 1 mm in from its ends (an offset there
    would be clamped, telling nothing).

    >>> pattern_lengths(4, 20.0).tolist()
    [1.0, 7.0, 13.0, 19.0]
    """
    return np.linspace(1.0, green_max_mm - 1.0, count)


def level_lengths_mm(cfg: Config, result: CalibrationResult, n_pixels: int, level: int
                     ) -> NDArray[np.float64]:
    """(N,) length (mm) every display pixel shows at ``level`` through ``result``'s tables."""
    from grassd.daemon.core.calibration.display_model import controller_pixels

    out = np.full(n_pixels, float(result.table_um[level]) / 1000.0)
    for c, pix in zip(cfg.controllers, controller_pixels(cfg.controllers, n_pixels),
                      strict=True):
        own = result.controller_tables.get(c.name)
        if own is not None:
            out[pix] = (own[:, level] if own.ndim == 2 else own[level]) / 1000.0
    return out


def run_measurement(ctx: MeasureContext) -> MeasurementOutcome:
    """One measurement (module docstring): its report, and what to keep when it was accepted.
    Raises :class:`MeasureDeadline` once ``[measure] deadline_s`` has passed (the display
    shows content again)."""
    from grassd.daemon.measure.camera_chain import MeasuringCamera
    from grassd.daemon.measure.evidence import shot_order
    from grassd.daemon.measure.patterns import PatternError, PatternSession

    cfg = ctx.cfg
    mc = cfg.measure
    t0 = time.perf_counter()
    deadline = _Deadline(mc.deadline_s)
    started = datetime.now(UTC)
    mid = measurement_id(started)
    n = cfg.display.rows * cfg.display.cols

    def progress(text: str) -> None:
        deadline.check(text)
        ctx.progress(text)

    progress("measure: tables without correction")
    nominal = ctx.calibrator.run(ctx.light, correction=None, progress=progress)
    t_cal = time.perf_counter()
    photos = Photos()
    lengths = pattern_lengths(mc.patterns, float(cfg.display.green_max_mm))
    cam = MeasuringCamera(ctx.camera, ctx.dest / mid, mc.iso)
    shots: dict[str, Shot] = {}
    states, order, repeat = _states_before(cfg, nominal, lengths, n)

    def shoot(name: str) -> None:
        if ctx.stop():
            raise RunInterrupted("measurement stopped (daemon shutting down)")
        progress(f"measure: photographing {name}")
        try:
            session.show(states[name])
        except PatternError:
            deadline.check(f"showing {name}")
            raise
        shots[name] = _within(deadline, ctx.stop, f"photographing {name}",
                              lambda: cam.shoot(name))
        session.wait_shown()  # pixels that moved during the shot are caught here
        photos.lux.append(float(ctx.lux()))
        _check_steady(photos.lux, mc.steady_lux)

    _within(deadline, ctx.stop, "setting the camera up", cam.prepare)  # before any pattern
    with PatternSession(ctx.fleet, cfg.controllers, n, timeout_s=mc.pattern_timeout_s,
                        settle_s=mc.settle_s,
                        stop=lambda: ctx.stop() or deadline.over) as session:
        for name in order:
            shoot(name)
        t_shoot = time.perf_counter()
        session.end()  # content while the photos are analysed (a minute or two)
        try:
            found = _analyse(ctx, mid, shots, photos, lengths, nominal, n, states, order,
                             repeat, progress)
        except PhotosRefused as exc:
            return MeasurementOutcome(_refused_report(mid, started, order, nominal,
                                                      exc.finding), None)
        corrected = found.correction.apply(cfg, nominal)
        after_names, _ = shot_order([f"after-{lv:03d}" for lv in CHECK_LEVELS])
        for lv in CHECK_LEVELS:
            states[f"after-{lv:03d}"] = level_lengths_mm(cfg, corrected, n, lv)
        for name in after_names:
            shoot(name)
    t_end = time.perf_counter()
    ctx.progress("measure: patterns ended, display shows content")
    names = [f"after-{lv:03d}" for lv in CHECK_LEVELS]
    after = _pixel_colours(ctx, shots, photos, names, found.located)
    evidence = _verify(found, names, after, np.stack([states[x] for x in names], axis=1),
                       (*order, *after_names))
    report = _report(ctx, mid, started, found, nominal, photos, after, lengths, n)
    report["seconds"] = {"calibrate": t_cal - t0, "photos_before": t_shoot - t_cal,
                         "analyse_and_after": t_end - t_shoot,
                         "total": time.perf_counter() - t0}
    evidence = _judged(report, evidence)
    return MeasurementOutcome(report, (found.correction, corrected) if evidence.accepted
                              else None)


def _check_steady(lux: list[float], steady: float) -> None:
    """Raise :class:`UnsteadyLight` when the ``lux`` read at the shots so far spread by more
    than the share ``steady`` (``[measure] steady_lux``)."""
    lo, hi = min(lux), max(lux)
    if hi > lo * (1.0 + steady):
        raise UnsteadyLight(f"the light changed from {lo:.0f} to {hi:.0f} lux while the "
                            f"display was photographed (over {steady:.0%}); measure at a "
                            "time of steady light")


def _states_before(cfg: Config, nominal: CalibrationResult, lengths: NDArray, n: int
                   ) -> tuple[dict[str, NDArray | float], list[str], str | None]:
    """The display states photographed before the correction, by shot name (every pixel's
    commanded length, mm: one for all, or (N,)): the shortest and longest grass, the patterns
    at ``lengths``, :data:`CHECK_LEVELS` through the ``nominal`` tables and the repeat; the
    order they are taken in, drawn for this measurement; the repeat's name (step 2 of the
    module docstring)."""
    from grassd.daemon.measure.evidence import shot_order

    uniform: dict[str, NDArray | float] = {"short": 0.0, "long": float(cfg.display.green_max_mm)}
    uniform.update({f"pattern-{k:02d}": float(x) for k, x in enumerate(lengths)})
    states: dict[str, NDArray | float] = {
        **uniform, **{f"before-{lv:03d}": level_lengths_mm(cfg, nominal, n, lv)
                      for lv in CHECK_LEVELS}}
    order, repeat = shot_order(list(states), repeat_of=list(uniform))
    if repeat is not None:
        states[repeat] = states[repeat.removeprefix("repeat-")]
    return states, order, repeat


def _refused_report(mid: str, started: datetime, order: list[str],
                    nominal: CalibrationResult, finding: Finding) -> MeasurementReport:
    """The report of a measurement whose photos could not even be analysed as the
    display's (``finding`` says why)."""
    return {"measurement": mid, "started_at": started.isoformat(timespec="seconds"),
            "status": "refused", "error": f"correction refused: {finding.detail}",
            "evidence": {"accepted": False, "order": order, "findings": [finding.to_json()]},
            "tables": {"granularity": "pixel", "nominal_source": nominal.source}}


def _judged(report: MeasurementReport, evidence: Evidence) -> Evidence:
    """``evidence`` with the last check, the display more uniform after the correction than
    before; written into ``report`` (its ``evidence``, and its ``status`` and ``error`` when
    refused)."""
    if not report["uniformity"]["after"] < report["uniformity"]["before"]:
        evidence = evidence.with_finding(Finding(
            Refusal.NOT_MORE_UNIFORM, "the correction did not make the display more uniform"))
    report["evidence"] = evidence.to_json()
    if not evidence.accepted:
        report.update(status="refused", error=f"correction refused: {evidence.reason()}")
    return evidence


class MeasureDeadline(MeasureError):
    """The whole measurement took longer than ``[measure] deadline_s``."""


class _Deadline:
    """The whole measurement's wall-clock limit (``seconds`` from now)."""

    def __init__(self, seconds: float) -> None:
        self.seconds = float(seconds)
        self.end = time.monotonic() + self.seconds

    @property
    def over(self) -> bool:
        """The deadline has passed."""
        return time.monotonic() >= self.end

    def left(self) -> float:
        """Seconds left (0 when passed)."""
        return max(self.end - time.monotonic(), 0.0)

    def check(self, doing: str) -> None:
        """Raise :class:`MeasureDeadline` (naming what was being done) once passed."""
        if self.over:
            raise MeasureDeadline(
                f"the measurement ran past [measure] deadline_s = {self.seconds:g} s (while "
                f"{doing.removeprefix('measure: ')}); the display shows content again and the "
                "last good tables stay: check that the measuring camera answers promptly, or "
                "raise deadline_s")


def _within(deadline: _Deadline, stop: Callable[[], bool], doing: str,
            work: Callable[[], T]) -> T:
    """``work()`` in a thread of its own, waited for until ``deadline`` (then
    :class:`MeasureDeadline`) or ``stop()`` (then RunInterrupted); a camera exchange left
    behind ends at its own timeouts."""
    out: list[T] = []
    err: list[BaseException] = []

    def run() -> None:
        try:
            out.append(work())
        except BaseException as exc:  # handed to the measurement's thread
            err.append(exc)

    worker = threading.Thread(target=run, name="grassd-measure-shot", daemon=True)
    worker.start()
    while worker.is_alive():
        worker.join(min(0.1, max(deadline.left(), 0.001)))
        if worker.is_alive():
            if stop():
                raise RunInterrupted("measurement stopped (daemon shutting down)")
            deadline.check(doing)
    if err:
        raise err[0]
    return out[0]


def _pixel_colours(ctx: MeasureContext, shots: dict[str, Shot], photos: Photos,
                   names: list[str], located: DisplayInPhoto) -> NDArray[np.float64]:
    """(N, len(names), 3) every pixel's mean normalised ProPhoto in the named shots."""
    from grassd.calib.display_in_photo import pixel_means
    from grassd.daemon.measure.camera_chain import develop_shot

    out = []
    for name in names:
        k = list(shots).index(name)
        img = develop_shot(shots[name], ctx.setup, photos.lux[k])
        out.append(pixel_means(img, located))
    return np.stack(out, axis=1)


def _analyse(ctx: MeasureContext, mid: str, shots: dict[str, Shot], photos: Photos,
             lengths: NDArray, nominal: CalibrationResult, n: int,
             states: dict[str, NDArray | float], order: list[str], repeat: str | None,
             progress: Callable[[str], None]) -> Analysis:
    """Locate, pose, colours, fit, the photos judged, correction (steps 3 to 5 of the module
    docstring); ``states``: every shot's commanded lengths (mm), ``order`` the shots as
    taken, ``repeat`` the repeated shot's name."""
    from grassd.calib.colour_spaces import prophoto_to_lab
    from grassd.calib.display_in_photo import pixel_means
    from grassd.daemon.core.calibration.display_model import display_spec_for_config
    from grassd.daemon.measure.evidence import judge, model_noise
    from grassd.daemon.measure.pixel_model import fit_variation, lab_of

    cfg, mc = ctx.cfg, ctx.cfg.measure
    progress("measure: finding the display in the photos")
    display = replace(display_spec_for_config(cfg), same_layout=True)  # the model pixel
    short, long_, located = _locate(ctx, shots, photos, display)
    pose = located.pose  # from the corners' and pixel centres' bearings
    eye = np.asarray(pose.position_m, dtype=np.float64)
    names = [f"pattern-{k:02d}" for k in range(len(lengths))]
    measured = prophoto_to_lab(_pixel_colours(ctx, shots, photos, names, located))
    before = _pixel_colours(ctx, shots, photos, [f"before-{lv:03d}" for lv in CHECK_LEVELS],
                            located)
    nominal_lengths = {lv: level_lengths_mm(cfg, nominal, n, lv) for lv in CHECK_LEVELS}
    # every photo at known commanded lengths informs the fit: the patterns, the all-short and
    # all-long pair (an offset shows most where the range clamps it) and the levels before
    ends = np.stack([pixel_means(short, located), pixel_means(long_, located)], axis=1)
    fit_lab = np.concatenate([prophoto_to_lab(ends), measured, prophoto_to_lab(before)], axis=1)
    fit_cmd = np.concatenate([np.tile([0.0, display.pixel.green_max_mm], (n, 1)),
                              np.tile(lengths, (n, 1)),
                              np.stack([nominal_lengths[lv] for lv in CHECK_LEVELS], axis=1)],
                             axis=1)
    models = PixelModels.for_measurement(cfg, ctx.light, display, progress)
    camera_model = models.from_eye(eye, "pixel models from the camera", mc.layouts)
    ccm = np.asarray(ctx.setup.ccm)
    progress("measure: fitting every pixel")
    fit = fit_variation(camera_model, fit_cmd, fit_lab, ccm)
    progress("measure: judging the photos")
    fit_names = ["short", "long", *(f"pattern-{k:02d}" for k in range(len(lengths))),
                 *(f"before-{lv:03d}" for lv in CHECK_LEVELS)]
    check_names, check_lab, check_cmd = fit_names, fit_lab, fit_cmd
    if repeat is not None:
        again = prophoto_to_lab(_pixel_colours(ctx, shots, photos, [repeat], located))
        check_names = [*fit_names, repeat]
        check_lab = np.concatenate([fit_lab, again], axis=1)
        check_cmd = np.concatenate([fit_cmd, np.broadcast_to(
            np.asarray(states[repeat], dtype=np.float64), (n,))[:, None]], axis=1)
    pairs = (check_lab[:, fit_names.index(repeat.removeprefix("repeat-"))], check_lab[:, -1]
             ) if repeat is not None else (check_lab[:, 0], check_lab[:, 0])
    def refit(kept: NDArray[np.bool_]) -> NDArray[np.float64]:  # the shots kept, fitted again
        progress("measure: fitting every pixel without the shots that disagree")
        used = kept[:len(fit_names)]  # the repeat is judged, not fitted
        again = fit_variation(camera_model, fit_cmd[:, used], fit_lab[:, used], ccm)
        return lab_of(camera_model.rgb(check_cmd, again.variation), again.colour @ ccm)

    evidence = judge(check_names, check_lab,
                     lab_of(camera_model.rgb(check_cmd, fit.variation), fit.colour @ ccm),
                     fit.rms_lab, fit.variation, pairs, model_noise(camera_model, fit_cmd),
                     order, refit)
    return Analysis(located, measured, before, camera_model, fit,
                    correction_for(cfg, models, fit.variation, mid), ccm, nominal_lengths, evidence)


def _locate(ctx: MeasureContext, shots: dict[str, Shot], photos: Photos, display: DisplaySpec
            ) -> tuple[NDArray[np.float64], NDArray[np.float64], DisplayInPhoto]:
    """The photos of the shortest and longest grass developed, and the display located from
    their difference (its camera pose too); :class:`PhotosRefused` when they do not show it."""
    from grassd.calib.display_in_photo import locate_display
    from grassd.calib.errors import GeometryError
    from grassd.daemon.measure.camera_chain import develop_shot

    taken = list(shots)
    short = develop_shot(shots["short"], ctx.setup, photos.lux[taken.index("short")])
    long_ = develop_shot(shots["long"], ctx.setup, photos.lux[taken.index("long")])
    try:
        located = locate_display(short, long_, display.rows, display.cols, display.pitch_mm,
                                 display.pixel.top_mm)
    except GeometryError as exc:
        raise PhotosRefused(Finding(
            Refusal.DISPLAY_NOT_FOUND, "the photos of the shortest and longest grass do not "
            f"show the display ({exc}): photos of other display states (old, or out of order) "
            "from the measuring camera, or [display] rows, cols, pitch_mm wrong",
            ("short", "long"))) from None
    return short, long_, located


@dataclass(frozen=True)
class PixelModels:
    """Records the model pixel at every pixel of ``display`` as an eye sees it
    (:func:`~grassd.daemon.measure.pixel_model.record_pixel_model`) under the measurement's
    light, on ``grid`` (mm, every :data:`GRID_STEP_MM`), read with the characteristic's
    ``transport`` (``[simulation] transport``; None: Rec.709)."""

    renderer: Renderer
    display: DisplaySpec
    lighting: Lighting
    grid: NDArray[np.float64]
    settings: RenderSettings
    progress: Callable[[str], None]
    transport: SpectralTransport | None = None

    @classmethod
    def for_measurement(cls, cfg: Config, light: LightInput, display: DisplaySpec,
                        progress: Callable[[str], None]) -> PixelModels:
        """The recorder of a measurement of ``cfg``'s display in ``light``: ``[measure]
        samples``."""
        from grassd.daemon.core.calibration.calibrate import Calibrator
        from grassd.daemon.core.calibration.display_model import capacity_for
        from grassd.sim.renderer import Renderer
        from grassd.sim.scene import RenderSettings

        # the pixel models are recorded here, whichever calibrator ran the tables (a Dask
        # cluster's runs only those), so their light is built here too
        calibrator = Calibrator(cfg)
        lighting = calibrator.lighting(light)
        return cls(Renderer.shared(capacity_for(display.rows * display.cols)), display,
                   lighting,
                   np.arange(0.0, display.pixel.green_max_mm + GRID_STEP_MM / 2, GRID_STEP_MM),
                   RenderSettings(samples=cfg.measure.samples, replicates=4,
                                  seed=cfg.simulation.seed), progress,
                   calibrator.transport(display, lighting))

    def from_eye(self, eye_m: NDArray, what: str, layouts: int) -> PixelColourModel:
        """Every pixel's model seen from the world point ``eye_m`` (m), averaged over
        ``layouts`` tuft layouts; progress told as ``what``."""
        from grassd.daemon.core.calibration.display_model import geometry_from_eye
        from grassd.daemon.measure.pixel_model import record_pixel_model

        geo = geometry_from_eye(self.display, eye_m)
        n = self.display.rows * self.display.cols
        return record_pixel_model(
            self.renderer, self.display, self.lighting, [geo.viewpoint(i) for i in range(n)],
            self.grid, self.settings, layouts=layouts, transport=self.transport,
            progress=lambda done, total: self.progress(f"measure: {what} {done}/{total}"))


def correction_for(cfg: Config, models: PixelModels, variation: DisplayVariation, mid: str
                   ) -> DisplayCorrection:
    """The correction of measurement ``mid``: the display's ``variation`` (the fitted one)
    carried to the configured viewers (step 5 of the module docstring)."""
    from grassd.daemon.core.calibration.correction import DisplayCorrection
    from grassd.daemon.measure.pixel_model import corrected_commands

    # the viewers' models only carry the fitted variation to them: the tuft layout's accident
    # is the same with and without it, so one layout does
    viewers = [models.from_eye(_eye_of(vp), f"viewer {i + 1}", 1)
               for i, vp in enumerate(cfg.viewpoints)]
    commands = corrected_commands(viewers, [vp.weight for vp in cfg.viewpoints],
                                  variation, models.grid)
    display = models.display
    return DisplayCorrection(variation, models.grid, commands,
                             (display.rows, display.cols), mid)


def _verify(found: Analysis, names: list[str], after: NDArray, commanded_mm: NDArray,
            order: tuple[str, ...]) -> Evidence:
    """The evidence of ``found`` with the verification photos judged: ``after`` (N, L, 3)
    their normalised ProPhoto, ``commanded_mm`` (N, L) the corrected lengths they showed,
    ``order`` every shot as taken."""
    from dataclasses import replace as dc_replace

    from grassd.calib.colour_spaces import prophoto_to_lab
    from grassd.daemon.measure.evidence import verify
    from grassd.daemon.measure.pixel_model import lab_of

    fit, model, ccm = found.fit, found.camera_model, found.ccm
    predicted = lab_of(model.rgb(commanded_mm, fit.variation), fit.colour @ ccm)
    ev = dc_replace(found.evidence, order=order)
    return verify(ev, names, prophoto_to_lab(after), predicted)


def _eye_of(vp: ViewpointConfig) -> NDArray[np.float64]:
    """World eye position (m) of a [[viewpoints]] entry standing relative to the display's
    centre (``grassd.sim.scene.Viewpoint.eye_m``)."""
    from grassd.sim.scene import Viewpoint

    return np.asarray(Viewpoint(vp.h_cm, vp.d_m, vp.theta_deg).eye_m((0.0, 0.0)))


def normalised_lab(rgb: NDArray, model: PixelColourModel, nominal_mm: NDArray, ccm: NDArray
                   ) -> NDArray[np.float64]:
    """(N, 3) CIELAB of every pixel's measured ``rgb`` (N, 3, normalised ProPhoto) with its
    viewing geometry divided out: rgb / (model pixel at its own viewpoint and ``nominal_mm``
    (N,)) x the display's mean of that model colour (module docstring)."""
    from grassd.calib.colour_spaces import prophoto_to_lab, rec709_to_prophoto
    from grassd.daemon.core.calibration.variation import DisplayVariation

    none = DisplayVariation.none(model.n_pixels)
    own = np.asarray(nominal_mm, dtype=np.float64)[:, None]  # each pixel at its own length
    m = rec709_to_prophoto(model.rgb(own, none)[:, 0]) @ np.asarray(ccm).T
    return prophoto_to_lab(rgb / np.clip(m, 1e-6, None) * m.mean(axis=0))


def uniformity(colours: NDArray, model: PixelColourModel, nominal: dict[int, NDArray],
               ccm: NDArray) -> Uniformity:
    """Uniformity of (N, levels, 3) measured colours at :data:`CHECK_LEVELS` (module
    docstring): worst pair at the mid level (dE00 and the two pixels), OGCD spread per
    level."""
    labs = np.stack([normalised_lab(colours[:, k], model, nominal[lv], ccm)
                     for k, lv in enumerate(CHECK_LEVELS)], axis=1)  # (N, L, 3)
    mid = labs[:, CHECK_LEVELS.index(MID_LEVEL)]
    pair = delta_E(mid[:, None, :], mid[None, :, :], method="CIE 2000")
    i, j = np.unravel_index(int(np.argmax(pair)), pair.shape)
    ogcd = delta_E(labs, labs[:, :1], method="CIE 2000")  # (N, L)
    return {"worst_pair_de00": float(pair[i, j]), "worst_pair": [int(i), int(j)],
            "ogcd_spread_de00": ogcd.std(axis=0).round(4).tolist(),
            "mean_ogcd_de00": ogcd.mean(axis=0).round(4).tolist()}


def _report(ctx: MeasureContext, mid: str, started: datetime, found: Analysis,
            nominal: CalibrationResult, photos: Photos, after: NDArray, lengths: NDArray,
            n: int) -> MeasurementReport:
    """The measurement's report (JSON-ready; written by
    :mod:`grassd.daemon.measure.report`)."""
    from grassd.calib.ogcd import ogcd_from_lab
    from grassd.daemon.core.calibration.variation import DisplayVariation
    from grassd.daemon.measure.pixel_model import lab_of

    mc = ctx.cfg.measure
    fit, model, ccm = found.fit, found.camera_model, found.ccm
    before_u = uniformity(found.before, model, found.nominal_lengths, ccm)
    after_u = uniformity(after, model, found.nominal_lengths, ccm)
    measured = found.measured_lab
    predicted = lab_of(model.rgb(lengths, DisplayVariation.none(n)), ccm)
    fitted = lab_of(model.rgb(lengths, fit.variation), fit.colour @ ccm)
    real_ogcd = np.stack([ogcd_from_lab(m) for m in measured])
    pred_ogcd = np.stack([ogcd_from_lab(m) for m in predicted])
    fit_ogcd = np.stack([ogcd_from_lab(m) for m in fitted])
    pose = found.located.pose
    eye = np.asarray(pose.position_m, dtype=float)
    b, a = before_u["worst_pair_de00"], after_u["worst_pair_de00"]
    within = a <= mc.tolerance_de00
    return {
        "measurement": mid, "started_at": started.isoformat(timespec="seconds"),
        "status": "ok",
        "camera": {"url": getattr(ctx.camera, "url", None),
                   "position_m": eye.round(4).tolist(),
                   "rms_deg": float(pose.rms_deg),
                   "viewpoint": {"h_cm": float(eye[2] * 100.0),
                                 "d_m": float(np.hypot(eye[0], eye[1])),
                                 "theta_deg": float(np.degrees(np.arctan2(eye[0], -eye[1])))}},
        "light": {"hdri": str(ctx.light.hdri), "lux": [round(x, 1) for x in photos.lux]},
        "patterns_mm": lengths.round(3).tolist(),
        "shape": [ctx.cfg.display.rows, ctx.cfg.display.cols],
        "display_colour_balance": np.diag(fit.colour).round(4).tolist(),
        "pixels": [{**p, "rms_lab": float(fit.rms_lab[p["index"]]),
                    "rms_lab_model": float(fit.rms_lab_model[p["index"]])}
                   for p in fit.variation.pixels()],
        "characteristic": {
            "lengths_mm": lengths.round(3).tolist(),
            "measured_ogcd": real_ogcd.round(3).tolist(),
            "predicted_ogcd": pred_ogcd.round(3).tolist(),
            "fitted_ogcd": fit_ogcd.round(3).tolist(),
            "max_error_predicted_de00": float(np.abs(real_ogcd - pred_ogcd).max()),
            "max_error_fitted_de00": float(np.abs(real_ogcd - fit_ogcd).max())},
        "uniformity": {"level": MID_LEVEL, "levels": list(CHECK_LEVELS), "before": b,
                       "after": a, "improvement": b / a if a > 0 else None,
                       "before_detail": before_u, "after_detail": after_u},
        "verdict": {"state": "within tolerance" if within else "recalibrate",
                    "tolerance_de00": mc.tolerance_de00,
                    "reason": (f"worst pixel pair {a:.2f} dE00 after correction (before "
                               f"{b:.2f}), tolerance {mc.tolerance_de00:g}")},
        "tables": {"granularity": "pixel", "nominal_source": nominal.source},
    }
