"""Simulated grass colour characteristics: the renderer (``sim``) composed with ``calib``.

``sim`` returns linear Rec.709 radiance (nits) with its Monte Carlo replicates; this module turns
it into CIELAB and OGCD the way a camera developed with a fixed white balance would see it
(with spectral transport's difference added to every replicate where asked:
:mod:`grassd.daemon.core.calibration.transport`):

1. White reference: the radiance of a perfect diffuse white lying flat at the display,
   ``W = E_h / pi`` per channel, where ``E_h`` is the horizontal irradiance of the lighting
   (environment plus sun). It is exact for an unoccluded card, so no render is needed.
2. Normalisation and white balance: every replicate is divided by ``W`` channel by channel
   (a von Kries white balance in linear Rec.709), so the white card reads (1, 1, 1), i.e. Y = 1
   at the D65 white, which the Bradford transform maps onto the D50 (ProPhoto/CIELAB) white.
   An 18 % grey card then reads Y = 0.18, the paper's exposure rule.
3. Optional colour-correction matrix (ProPhoto linear), then Lab and OGCD with
   correlation-aware standard errors from the replicates
   (:func:`grassd.calib.ogcd.ogcd_from_samples`; the replicates share random numbers across
   lengths, so their covariance is what makes the OGCD error small).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING

import numpy as np

from grassd.calib.ogcd import ogcd_from_samples
from grassd.sim.errors import SceneError
from grassd.sim.scene import MAX_REPLICATES, DisplaySpec

if TYPE_CHECKING:
    from grassd.daemon.core.calibration.transport import SpectralTransport


@dataclass(frozen=True)
class SimulatedCurve:
    """One viewpoint's simulated characteristic.

    ``rgb_linear``/``rgb_stderr`` (n, 3): radiance in the scaled HDRI's units (nits), no
    normalisation; ``lab`` (n, 3) D50 CIELAB after normalisation (and CCM if given); ``ogcd``
    and ``ogcd_stderr`` (n,) in CIEDE2000 units. ``replicates``: of the reference length (the
    most); ``length_replicates`` (n,): of each length (an adaptive run stops tracing a length
    once its error meets the target). ``rounds``: (replicates so far, largest OGCD stderr then)
    after each batch of an adaptive run, one entry otherwise. ``paths_traced``: camera path
    traces the renderer ran (a path is traced again only at lengths where it may change).
    ``step_stderr`` (n - 1,): standard errors of OGCD's steps between neighbouring lengths
    [dE00] when every length shares its replicates (None after an adaptive run stopped some
    lengths early; :class:`grassd.calib.ogcd.OGCDResult`).
    """

    h_cm: float
    d_m: float
    theta_deg: float
    lengths_mm: np.ndarray
    rgb_linear: np.ndarray
    rgb_stderr: np.ndarray
    lab: np.ndarray
    ogcd: np.ndarray
    ogcd_stderr: np.ndarray
    replicates: int = 0
    seconds: dict[str, float] = field(default_factory=dict)
    rounds: tuple[tuple[int, float], ...] = ()
    length_replicates: np.ndarray | None = None
    paths_traced: int = 0
    step_stderr: np.ndarray | None = None

    def to_json(self) -> dict:
        """The per-viewpoint JSON object of ``grassd simulate --json``."""
        return {
            "h_cm": self.h_cm, "d_m": self.d_m, "theta_deg": self.theta_deg,
            "lengths_mm": self.lengths_mm.tolist(), "rgb_linear": self.rgb_linear.tolist(),
            "rgb_stderr": self.rgb_stderr.tolist(), "lab": self.lab.tolist(),
            "ogcd": self.ogcd.tolist(), "ogcd_stderr": self.ogcd_stderr.tolist(),
            "replicates": self.replicates,
            "length_replicates": None if self.length_replicates is None
            else self.length_replicates.tolist(),
        }


#: Seed offset between the tuft layouts of one round (a prime apart from the rounds' 7919).
LAYOUT_SEED_STEP: int = 104729


def layout_seed(seed: int, layout: int) -> int:
    """The path seed of tuft layout ``layout`` (0, 1, ...) of a simulation seeded ``seed``:
    layout 0 keeps the seed, the others draw their own paths."""
    return (seed + LAYOUT_SEED_STEP * layout) % 2**31


def layout_display(display: DisplaySpec, layout: int) -> DisplaySpec:
    """The display of tuft layout ``layout`` (0, 1, ...) of a simulation: its pixel's
    ``layout_seed`` moved by ``layout`` (layout 0 is the display itself), traced with the
    paths of :func:`layout_seed`."""
    if layout == 0:
        return display
    return replace(display, pixel=replace(display.pixel,
                                          layout_seed=display.pixel.layout_seed + layout))


@dataclass(frozen=True)
class LargerReplicates:
    """When an adaptive run under a sun (a light with a sun direction) finds from its first
    camera paths (per length: ``sun_look_paths``, judged again at ``look_paths``, see below)
    that the target needs more than ``after_paths``, the run starts a new series of replicates of
    ``samples`` paths each (at least ``least`` of them before it stops at the target: their
    spread is the error), and the paths so far were only the first look.

    Why: a replicate's paths are a scrambled Sobol' net over the measurement quad, and where
    the quad's radiance has sharp edges (a low sun's light and shadow on the blades) a larger
    net's error falls faster than 1/sqrt(paths). Under diffuse light (no sun) the error goes as
    1/sqrt(paths) whatever the replicates' size, so a run without a sun keeps its small
    replicates: there a larger series gains nothing per path, costs at least ``least`` x
    ``samples`` paths, and a first look overstates the paths needed often enough to switch
    where it should not.

    Under a sun the larger series also takes ``light_samples`` environment samples at the first
    surface and Russian roulette from surface ``roulette_from`` on (:class:`RenderSettings`):
    its noise is the first surface's light and shadow, which neither the environment's light
    samples nor the later bounces reduce, so they only cost time.

    Under a sun the run judges its paths from ``sun_look_paths`` on (the first round), and
    judges again at ``look_paths`` if that first look said the target was near: a first look
    that switches saves the second round of small replicates, and one that misjudged the paths
    needed is caught at the second.

    The measurements that chose each default: docs/renderer/measurements.md."""

    samples: int = 8192
    after_paths: int = 65536
    look_paths: int = 8192
    sun_look_paths: int = 4096
    least: int = 8
    light_samples: int = 1
    roulette_from: int = 1


def white_radiance(lighting) -> np.ndarray:
    """Linear Rec.709 radiance (nits) of a perfect diffuse white lying flat at the display."""
    return np.asarray(lighting.horizontal_irradiance_rgb, dtype=np.float64) / math.pi


def simulate_curve(renderer, display, lighting, viewpoint, lengths_mm: np.ndarray, settings,
                   *, ccm=None, pixel_index: int = 0, target_stderr: float | None = None,
                   max_replicates: int = 256, layouts: int = 1,
                   progress: Callable[[int, int], None] | None = None,
                   on_round: Callable[[SimulatedCurve], None] | None = None,
                   round_replicates: int = MAX_REPLICATES,
                   larger: LargerReplicates | None = None,
                   resume: CurveRun | None = None,
                   spectral: SpectralTransport | None = None) -> SimulatedCurve:
    """Render one viewpoint at ``lengths_mm`` (mm, first = reference) and derive its OGCD.

    With ``target_stderr`` (CIEDE2000), further batches of independent replicates (new seeds,
    same random numbers across lengths within a replicate) are traced until every OGCD
    standard error is at most the target or ``max_replicates`` is reached; a round traces
    the reference and the lengths still above the target in one launch (:func:`_next_round`).
    The first round needs at least 2 replicates (their spread is the error).

    ``layouts``: replicate j traces the display with ``layout_seed + (j mod layouts)`` and its
    own paths (:func:`layout_seed`), so the curve is the mean over that many random tuft
    layouts (as many as the first round's replicates at most; equal weights when they divide
    the replicates) and its standard error holds their spread. The installed pixels' tufts
    are none of them, so the mean of several is the truer target (docs/calibration.md).

    ``on_round`` is called with the curve so far after every round (an interactive view
    refines as they arrive); an exception it raises ends the run. ``round_replicates`` caps
    the replicates a later round adds (an interactive view keeps its rounds short, so that a
    new input waits little for the round in flight).

    ``larger``: with a target and a sun, replicates of more paths where the first paths say
    the target needs many (:class:`LargerReplicates`). ``resume``: the run's state, kept by
    the caller so that a stopped run goes on where it stopped (:class:`CurveRun`).
    ``spectral``: each replicate adds the difference spectral transport makes to its paths
    (:class:`grassd.daemon.core.calibration.transport.SpectralTransport`, for this display and
    light); None: Rec.709 transport alone."""
    if settings.replicates < 2:
        raise SceneError(f"simulate_curve needs at least 2 replicates (their spread is the "
                         f"error); got {settings.replicates}")
    if layouts < 1:
        raise SceneError(f"layouts must be at least 1, got {layouts}")
    lengths_mm = np.asarray(lengths_mm, float)
    white = white_radiance(lighting)
    if lighting.sun_direction is None:  # under diffuse light larger replicates gain nothing
        larger = None
    run = CurveRun() if resume is None else resume
    fresh = run.start(settings, len(lengths_mm), max_replicates, round_replicates, (
        tuple(lengths_mm.tolist()), settings, target_stderr, max_replicates, round_replicates,
        layouts, pixel_index, larger, spectral is None))
    tracer = _RoundTracer(renderer, display, lighting, viewpoint, lengths_mm, layouts,
                          pixel_index, progress, run.seconds, spectral)
    first_round = settings.replicates
    if (not fresh and on_round is not None and run.shown is not None
            and (not run.blocks or int(run.counts[0]) < run.show_from)):
        on_round(run.shown)  # the current series has nothing to show yet: the last shown
    while True:
        if run.decided and (fresh or not run.blocks):  # a resumed run first shows its last
            seed = (run.settings.seed + 7919 * run.k) % 2**31  # round, if it has one
            block, paths = tracer.round(run.cols, replace(run.settings, seed=seed), run.b,
                                        int(run.counts[0]))
            run.add_round(block, paths)
        fresh = True
        x, lab, ogcd, se, step_se = run.colours(white, ccm)
        counts = run.counts
        n = int(counts[0])
        worst = float(np.max(se))
        rounds = run.rounds if run.decided else [*run.rounds, (n, worst)]
        done = (target_stderr is None or (worst <= target_stderr and n >= run.least)
                or n >= run.max_replicates)
        shown = on_round is not None and n >= run.show_from
        curve = None
        if shown or done:
            curve = run.curve(viewpoint, lengths_mm, x, lab, ogcd, se, step_se, rounds)
        if not run.decided:  # the next round, decided before the curve is shown (which may
            # stop the run); what may raise comes first, the run's state changes last
            _decide_next(run, larger, se, counts, target_stderr, first_round, done)
        if shown:
            run.shown = curve
            on_round(curve)
        if done:
            return curve


def _decide_next(run: CurveRun, larger: LargerReplicates | None, se: np.ndarray,
                 counts: np.ndarray, target_stderr: float | None, first_round: int,
                 done: bool) -> None:
    """Decide ``run``'s next round from this one's OGCD standard errors ``se`` [dE00] and
    replicate ``counts`` per length: a new series of larger replicates, or the lengths and
    replicates the target still needs (none when ``done``); the round is then recorded."""
    n, worst = int(counts[0]), float(np.max(se))
    if not done:
        nxt = (None if _larger_series(run, larger, n, worst, target_stderr, first_round)
               else _next_round(se, counts, target_stderr, run.least,
                                min(run.max_replicates - n, run.round_replicates,
                                    MAX_REPLICATES)))
        if nxt is not None:
            run.b, run.cols = nxt
        run.k += 1
    run.rounds.append((n, worst))
    run.decided = True


@dataclass
class CurveRun:
    """Where an adaptive :func:`simulate_curve` run stands after its last complete round, the
    next round decided: what the run needs to go on where it stopped (a newer input stops the
    studio's runs; it keeps them per condition). Empty until the run begins.

    A run that an exception stopped (a newer input, raised by ``on_round`` or ``progress``)
    goes on from its last complete round when :func:`simulate_curve` is called again with
    the same state and arguments, first showing ``on_round`` that round's curve (or the last
    one shown, where a new series of larger replicates has too few yet); the rounds and seeds
    are those of a run never stopped, so the curve is the same. With larger replicates,
    ``max_replicates`` and ``round_replicates`` count paths as the first series' replicates
    do (scaled by their sizes), and ``on_round`` sees the new series once it has as many
    replicates as the first round had."""

    settings: object = None  #: RenderSettings of the current series (None: not begun)
    k: int = 0  #: rounds traced: the next round's seed is ``seed + 7919 k``
    b: int = 0  #: replicates of the next round
    cols: np.ndarray | None = None  #: the lengths (indices) the next round traces
    blocks: list[np.ndarray] = field(default_factory=list)  #: per round (b, n, 3), NaN: not
    #: traced (linear RGB, nits) since the current series began
    counts: np.ndarray | None = None  #: replicates of each length: always the first ones
    rounds: list[tuple[int, float]] = field(default_factory=list)
    cache: dict = field(default_factory=dict)  #: :meth:`colours`' of the series
    show_from: int = 0  #: replicates before a round is shown
    least: int = 0  #: replicates before the run may stop
    looked: bool = False  #: whether ``larger`` has judged the first paths
    traced_paths: int = 0
    decided: bool = True  #: whether the next round is decided (False: a round just traced)
    asked: tuple = ()  #: what the run was asked (lengths, settings, target, limits)
    shown: SimulatedCurve | None = None  #: the curve last shown to ``on_round``
    max_replicates: int = 0
    round_replicates: int = 0
    seconds: dict[str, float] = field(
        default_factory=lambda: {"compile": 0.0, "trace": 0.0, "spectral": 0.0, "colour": 0.0})

    def start(self, settings, n_len: int, max_replicates: int, round_replicates: int,
              asked: tuple) -> bool:
        """Begin the run (True; its first round traces every length with ``settings``), or
        go on with a stopped one (False) that was asked the same (``asked``: lengths,
        settings, target, limits)."""
        if self.settings is not None:
            if self.asked != asked:
                raise SceneError("a stopped run goes on only with the lengths, settings, "
                                 "target and limits it began with")
            return False
        self.settings, self.b, self.asked = settings, settings.replicates, asked
        self.cols, self.counts = np.arange(n_len), np.zeros(n_len, np.int64)
        self.max_replicates, self.round_replicates = max_replicates, round_replicates
        return True

    def add_round(self, block: np.ndarray, paths: int) -> None:
        """Take a traced round: ``block`` (b, n, 3) of ``paths`` camera paths."""
        self.traced_paths += paths
        self.blocks.append(block)
        self.counts[self.cols] += self.b
        self.decided = False

    def colours(self, white: np.ndarray, ccm
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
        """The series' replicates ``x`` (R, n, 3) linear RGB [nits], and their Lab (n, 3),
        OGCD and its standard error (n,) after normalising by ``white``, length i traced in
        the first ``counts[i]`` replicates (a round traces the reference, column 0, and the
        lengths still above the target, so a length's replicates are those of the rounds
        before it met it): the lengths with the same count are taken together with the
        reference over those replicates, each group once while its replicates do not change
        (``cache``). Last: the steps' standard errors (n - 1,) when every length has the
        same replicates, else None. Timed as the run's ``colour`` seconds."""
        t0 = time.perf_counter()
        x, counts, cache = np.concatenate(self.blocks), self.counts, self.cache
        n = x.shape[1]
        lab = np.empty((n, 3))
        ogcd = np.zeros(n)
        se = np.zeros(n)
        for c in np.unique(counts):  # ascending: the reference's (the most) last
            cols = np.flatnonzero(counts == c)
            cols = np.concatenate([[0], cols[cols != 0]])
            key = (int(c), cols.tobytes())
            if key not in cache:  # a finished length's numbers do not change
                res = ogcd_from_samples(np.clip(x[:c][:, cols] / white, 0.0, None),
                                        space="rec709", ccm=ccm)
                cache[key] = (res.lab, res.ogcd, res.ogcd_stderr, res.step_stderr)
            lab[cols], ogcd[cols], se[cols], step_se = cache[key]
        self.seconds["colour"] += time.perf_counter() - t0
        return x, lab, ogcd, se, step_se if len(np.unique(counts)) == 1 else None

    def curve(self, viewpoint, lengths_mm: np.ndarray, x: np.ndarray, lab: np.ndarray,
              ogcd: np.ndarray, ogcd_se: np.ndarray, step_se: np.ndarray | None,
              rounds: list[tuple[int, float]]) -> SimulatedCurve:
        """The curve of the series so far: ``x`` (R, n, 3) its replicates' radiance (nits,
        NaN where a replicate did not trace a length), their CIELAB, OGCD and its standard
        errors (dE00), ``rounds`` as :attr:`SimulatedCurve.rounds`."""
        counts = self.counts
        return SimulatedCurve(
            h_cm=viewpoint.h_cm, d_m=viewpoint.d_m, theta_deg=viewpoint.theta_deg,
            lengths_mm=lengths_mm, rgb_linear=np.nanmean(x, axis=0),
            rgb_stderr=np.nanstd(x, axis=0, ddof=1) / np.sqrt(counts)[:, None], lab=lab,
            ogcd=ogcd, ogcd_stderr=ogcd_se, replicates=int(counts[0]),
            seconds=dict(self.seconds), rounds=tuple(rounds), length_replicates=counts.copy(),
            paths_traced=self.traced_paths, step_stderr=step_se)


def _larger_series(run: CurveRun, larger: LargerReplicates | None, n: int, worst: float,
                   target_stderr: float | None, first_round: int) -> bool:
    """Judge ``run``'s first paths for ``larger`` (``n`` replicates so far, largest OGCD
    standard error ``worst``, dE00) and, where the target needs more than ``after_paths``,
    start a new series of larger replicates as the next round (True)."""
    settings = run.settings
    if (larger is None or run.looked or larger.samples <= settings.samples
            or n * settings.samples < larger.sun_look_paths):
        return False
    run.looked = n * settings.samples >= larger.look_paths  # else judged again there
    needed = n * (worst / target_stderr) ** 2 * settings.samples  # paths, 1/sqrt law
    if needed <= larger.after_paths:
        return False
    scale = larger.samples / settings.samples
    # fewer light samples and bounces: the noise is the first surface's light and shadow
    run.settings = replace(settings, samples=larger.samples,
                           light_samples=larger.light_samples,
                           roulette_from=larger.roulette_from)
    run.max_replicates = max(larger.least, int(run.max_replicates / scale))
    run.round_replicates = max(1, int(run.round_replicates / scale))
    run.show_from, run.least = min(first_round, larger.least), larger.least
    run.blocks, run.cache = [], {}
    run.counts[:] = 0
    run.cols = np.arange(len(run.counts))
    run.b = max(2, min(run.least, run.round_replicates))  # its first round: a spread
    return True


@dataclass(frozen=True)
class _RoundTracer:
    """What every round of one :func:`simulate_curve` run traces: the display seen from
    ``viewpoint`` under ``lighting`` at ``lengths_mm`` (mm), with ``layouts`` tuft layouts,
    with ``spectral`` transport's difference where given; the renderer's compile and trace
    seconds (and the recording's, as ``spectral``) are added to ``seconds``."""

    renderer: object
    display: object
    lighting: object
    viewpoint: object
    lengths_mm: np.ndarray
    layouts: int
    pixel_index: int
    progress: Callable[[int, int], None] | None
    seconds: dict[str, float]
    spectral: SpectralTransport | None = None

    def round(self, cols: np.ndarray, settings, b: int, first: int) -> tuple[np.ndarray, int]:
        """Trace a round of ``b`` replicates (the run's ``first`` to ``first + b - 1``, seeded
        from ``settings.seed``) at the lengths ``lengths_mm[cols]``: replicate j traces tuft
        layout j mod ``layouts`` (:func:`layout_seed`). Returns the round's linear RGB [nits]
        (b, n, 3), NaN at the lengths not traced, and the camera paths traced."""
        block = np.full((b, len(self.lengths_mm), 3), np.nan)
        traced_paths = 0
        for layout in sorted({(first + i) % self.layouts for i in range(b)}):
            rows = [i for i in range(b) if (first + i) % self.layouts == layout]
            display = layout_display(self.display, layout)
            layout_settings = replace(settings, replicates=len(rows),
                                      seed=layout_seed(settings.seed, layout))
            m = self.renderer.characteristic(
                display, self.lighting, self.viewpoint, self.lengths_mm[cols], layout_settings,
                pixel_index=self.pixel_index, progress=self.progress)
            self.seconds["compile"] += m.seconds.get("compile", 0.0)
            self.seconds["trace"] += m.seconds.get("trace", 0.0)
            traced_paths += m.paths_traced
            rgb = m.rgb_replicates
            if self.spectral is not None:
                difference, seconds = self.spectral.difference(
                    self.renderer, display, self.lighting, self.viewpoint,
                    self.lengths_mm[cols], layout_settings, self.pixel_index)
                rgb = rgb + difference
                self.seconds["spectral"] += seconds
            block[np.ix_(rows, cols)] = rgb
        return block, traced_paths


def _next_round(se: np.ndarray, counts: np.ndarray, target_stderr: float, least: int,
                most: int) -> tuple[int, np.ndarray]:
    """The next round of an adaptive run: how many replicates (at most ``most``), and the
    lengths (indices, the reference 0 always) that trace them, in one launch (the renderer
    traces a path once for all its lengths). Until the series has ``least`` replicates every
    length takes them; then the lengths whose OGCD standard error ``se`` (dE00) is above the
    target take what the 1/sqrt(R) law says the neediest of them needs, at least one
    replicate and (as the worst of n noisy estimates overstates the error: the first round's
    estimate often lands just above the target) at most doubling its count. A length's OGCD
    and its error come from the replicates that traced it (the reference's from the same
    ones, so the common random numbers keep cancelling); a length at or below the target
    keeps them."""
    above = se > target_stderr
    n = int(counts[0])
    if n < least:
        above[:] = True
        b = least - n
    else:
        ratio = np.minimum((se[above] / target_stderr) ** 2, 2.0)
        b = int(np.max(np.maximum(np.ceil(counts[above] * ratio) - counts[above], 1)))
    return min(b, most), np.union1d([0], np.flatnonzero(above))


def simulate_curves(renderer, display, lighting, viewpoints: Sequence, lengths_mm: np.ndarray,
                    settings, *, ccm=None, pixel_index: int = 0,
                    target_stderr: float | None = None,
                    spectral: SpectralTransport | None = None,
                    progress: Callable[[int], None] | None = None
                    ) -> tuple[list[SimulatedCurve], dict[str, float]]:
    """:func:`simulate_curve` for every viewpoint (with ``spectral`` transport where given);
    returns the curves and summed seconds (``compile``, ``trace``, ``spectral``, ``colour``,
    ``total``). ``progress(k)`` is called with the number of
    lengths finished since the last call."""
    t0 = time.perf_counter()
    curves = []
    for vp in viewpoints:
        done = [0]

        def step(k: int, _n: int, done=done) -> None:
            if progress and k > done[0]:  # later adaptive batches restart at 0: not counted
                progress(k - done[0])
                done[0] = k

        curves.append(simulate_curve(renderer, display, lighting, vp, lengths_mm, settings,
                                     ccm=ccm, pixel_index=pixel_index,
                                     target_stderr=target_stderr, progress=step,
                                     spectral=spectral))
    seconds = {k: float(sum(c.seconds.get(k, 0.0) for c in curves))
               for k in ("compile", "trace", "spectral", "colour")}
    seconds["total"] = time.perf_counter() - t0
    return curves, seconds
