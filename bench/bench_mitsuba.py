"""grassd against Mitsuba 3 (``llvm_ad_rgb``) on the exported scene: efficiency and agreement.

The scene is what ``grassd simulate export-scene`` writes for courtyard and forest at
5000 lx, view (170, 2, 0), green length 10 mm; Mitsuba renders it with its ``path`` integrator
(``max_depth`` 4 = 3 bounces, no Russian roulette), the ``independent`` sampler at 4 spp, the
film cropped to the quad's bounding box and each pixel weighted by its exact coverage of the
quad (:mod:`grassd.rigs.mitsuba_scene`). grassd traces the same quad at the one length and as
the 21-length characteristic 0..20 mm, twice: with its default settings (4096 paths x 8
replicates), and at Mitsuba's noise (as many replicates of 4096 paths as make
grassd's G at one length about as noisy as one Mitsuba render, chosen by untimed pilots of both
sides, the grassd pilot's variance good to about +-15 %). The second setting traces more
replicates of the same estimator, so the two differ only in grassd's seconds per replicate
(larger launches); it checks that the default's noise level does not flatter or wrong grassd.
Mitsuba stays at 4 spp: it pays a fixed cost per render (forest: 1 spp took
0.148 s, 4 spp 0.439 s), so at grassd's default noise (1-2 spp) it would be less efficient.

Efficiency = 1 / (seconds x relative variance of the quad's G), both sides measured in the same
process, interleaved round by round (the CPU is shared, so timings drift together), with wall
seconds (medians) and, less sensitive to other processes, CPU seconds of the process (all its
threads). Each ratio is printed from the medians over all rounds and, as median [quartiles], round
by round (both sides' times from the same round, so the machine's drift between rounds weighs less;
the variances are the pooled ones). Scene load, upload and JIT are not timed. Each timed call
starts after a ``SETTLE_S`` pause: Dr.Jit's worker threads keep spinning for a few milliseconds
after a render, and grassd timed right after one ran about 25 % slower (forest: 0.054 s against
0.040-0.044 s with a 10 ms to 1 s pause; Mitsuba's own time did not move; on a second CPU,
with the pause, grassd's forest one length took 90.2 ms after a Mitsuba render and 90.3 ms after
a call of its own, medians of 12). The variance of one
Mitsuba render comes from its pixels: they are independent, so ``sum_i w_i^2 s_i^2 / (sum w)^2``
with s_i^2 each pixel's variance over the renders; grassd's from its replicates, all of them
pooled: every replicate of either setting, at one length or at 10 mm of the 21, is a draw of the
same estimator of 4096 paths (a length's radiance does not depend on the other lengths traced),
so both settings share one variance per replicate, known to about +-5-6 % from 10 rounds (each
setting's own replicates alone moved its efficiency by +-15 % in 10 rounds, 2x in 3). For the
characteristic Mitsuba counts as 21 renders and both sides use the variance at 10 mm. Agreement:
the pooled means per channel, their difference in % and in combined standard errors; Mitsuba's side
for it is measured exactly (camera rays uniform over the quad,
:func:`grassd.rigs.mitsuba_scene.quad_mean`, untimed), as the film's partly covered pixels carry
light from outside the quad (printed too).

Run: ``python -m bench mitsuba``. Needs the test extra (mitsuba) and libLLVM >= 16 (Debian:
``apt-get install libllvm19``); without either it prints one line and skips.
``GRASSD_BENCH_MITSUBA_ROUNDS`` (default 10) sets the rounds, ``GRASSD_BENCH_MITSUBA_SCENES``
a comma list of panoramas.
"""

from __future__ import annotations

import os
import tempfile
import time
from pathlib import Path

import numpy as np

from bench import HDRI_DIR

LUX = 5000.0
LENGTH_MM = 10.0
LENGTHS_MM = np.arange(0.0, 20.01, 1.0)
SPP = 4
WIDTH = 512  #: film width (export-scene's default)
RENDERS_PER_ROUND = 2
EXACT_RAYS = 1 << 20  #: Mitsuba paths per round for the agreement (untimed)
SETTLE_S = 0.05  #: pause before each timed call, so neither side runs beside the other's threads
PILOT_RENDERS = 4  #: untimed Mitsuba renders that set grassd's replicates at Mitsuba's noise
PILOT_SEEDS = range(200_000, 200_012)  #: grassd's untimed pilot calls (seeds no round uses)
PILOT_MITSUBA_SEED = 1 << 24  #: first seed of Mitsuba's pilot renders (beyond the rounds' seeds)


def _skip_reason() -> str | None:
    from grassd.rigs.mitsuba_scene import configure_llvm

    try:
        import mitsuba  # noqa: F401
    except ImportError:
        return "mitsuba not installed (pip install -e '.[test]')"
    if configure_llvm() is None:
        return "no libLLVM >= 16 for Dr.Jit's llvm variant (apt-get install libllvm19)"
    if not HDRI_DIR.is_dir():
        return f"{HDRI_DIR} absent (the shared HDRIs)"
    return None


class MitsubaSide:
    """One exported scene in Mitsuba: the cropped film (timed; the exported map as it is, as a
    user would render it) and the exact quad measurement for the agreement (the map resampled
    to Mitsuba's convention, camera rays uniform over the quad: no partly covered pixels)."""

    def __init__(self, scene_dir: Path, width: int = WIDTH, spp: int = SPP) -> None:
        import mitsuba as mi

        from grassd.rigs.mitsuba_scene import quad_coverage, read_doc, scene_dict

        self.mi = mi
        self.doc = read_doc(scene_dir)
        (x0, y0), self.weights = quad_coverage(self.doc, width)
        h, w = self.weights.shape
        self.scene = mi.load_dict(scene_dict(scene_dir, spp, width, crop=((x0, y0), (w, h)),
                                             env_refine=0))
        self.exact_scene = mi.load_dict(scene_dict(scene_dir, 1, 64))
        self.images: list[np.ndarray] = []
        self.seconds: list[float] = []
        self.cpu_seconds: list[float] = []
        self.exact: list[np.ndarray] = []
        self._seed = 1 << 20
        self.render(keep=False)  # JIT, not timed
        self.measure_exact(keep=False)

    def pilot_relvar(self, renders: int = PILOT_RENDERS) -> float:
        """Relative variance of one render's G, from ``renders`` untimed renders (not kept), on
        seeds of their own, so the timed renders keep theirs."""
        images = [self.render(keep=False, seed=PILOT_MITSUBA_SEED + k) for k in range(renders)]
        mean, _, var = self.estimate(images)
        return float(var[1] / mean[1] ** 2)

    def render(self, keep: bool = True, seed: int | None = None) -> np.ndarray:
        """One render of the cropped film (linear RGB, (h, w, 3)); timed and kept with
        ``keep``. ``seed``: the next of the bench's own sequence unless given."""
        if seed is None:
            self._seed += 1
            seed = self._seed
        time.sleep(SETTLE_S)
        t0, c0 = time.perf_counter(), time.process_time()
        img = np.array(self.mi.render(self.scene, seed=seed), dtype=np.float64)[..., :3]
        dt, dc = time.perf_counter() - t0, time.process_time() - c0
        if keep:
            self.images.append(img)
            self.seconds.append(dt)
            self.cpu_seconds.append(dc)
        return img

    def measure_exact(self, keep: bool = True) -> None:
        from grassd.rigs.mitsuba_scene import quad_mean

        self._seed += 1
        rgb = quad_mean(self.exact_scene, self.doc, EXACT_RAYS, self._seed)
        if keep:
            self.exact.append(rgb)

    def estimate(self, images: list[np.ndarray] | None = None
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(mean RGB over renders, its standard error, variance of one render's RGB), of the
        kept renders or of ``images``."""
        imgs = np.stack(self.images if images is None else images)  # (n, h, w, 3)
        w = self.weights / self.weights.sum()
        per_render = np.einsum("nhwc,hw->nc", imgs, w)
        var_one = np.einsum("hwc,hw->c", imgs.var(axis=0, ddof=1), w * w)
        return per_render.mean(axis=0), np.sqrt(var_one / len(imgs)), var_one


def _spread(ratios: np.ndarray) -> str:
    """``median [q25, q75]x`` of per-round efficiency ratios."""
    q25, q50, q75 = np.percentile(ratios, [25, 50, 75])
    return f"{q50:.2f}x [{q25:.2f}, {q75:.2f}]"


def _relvar(g: np.ndarray) -> float:
    """Relative variance of one grassd replicate's G, from replicate means ``g`` (nits)."""
    return float(g.var(ddof=1) / g.mean() ** 2)


def _efficiencies(name: str, label: str, g: dict, rv: float, m: MitsubaSide, rv_m: float
                  ) -> None:
    """Print grassd's and Mitsuba's efficiencies and their ratios for one grassd setting
    (``label``; ``rv``: the relative variance of its G at 10 mm, one length or 21), with wall
    and CPU seconds: overall (medians) and round by round."""
    n = len(LENGTHS_MM)
    for clock, m_s, g1, g21 in (("wall", m.seconds, g["t1"], g["t21"]),
                                ("CPU", m.cpu_seconds, g["c1"], g["c21"])):
        t_m, t1, t21 = np.median(m_s), np.median(g1), np.median(g21)
        e_m, e1, e21 = 1 / (t_m * rv_m), 1 / (t1 * rv), 1 / (t21 * rv)
        # the same ratios round by round (each side's time in that round), where the machine's
        # drift between rounds cancels
        m_r = np.median(np.reshape(m_s, (-1, RENDERS_PER_ROUND)), axis=1)
        r1 = m_r * rv_m / (np.asarray(g1) * rv)
        r21 = m_r * rv_m * n / (np.asarray(g21) * rv)
        print(f"{name}, {label}: efficiency 1/({clock} s x relvar G): one length grassd "
              f"{e1:.3g}, Mitsuba {e_m:.3g}, ratio {e1 / e_m:.2f}x; 21 lengths grassd {e21:.3g}, "
              f"Mitsuba {e_m / n:.3g} ({n} renders), ratio {e21 / (e_m / n):.2f}x; round by "
              f"round {_spread(r1)} and {_spread(r21)}")


def _summary(name: str, samples: np.ndarray, runs: dict[str, tuple[int, dict]],
             m: MitsubaSide, traces: tuple[float, float]) -> None:
    """Print efficiencies (wall and CPU seconds) and the agreement of one scene. ``samples``
    (n, 3): every grassd replicate's RGB at 10 mm, one length or 21, both settings: draws of
    one estimator (a length's radiance does not depend on the other lengths traced), pooled
    for its variance. ``runs``: per grassd setting (label), its replicates and its seconds per
    round ("t1", "t21", "c1", "c21": wall/CPU, one/21 lengths)."""
    from grassd.sim.scene import RenderSettings

    g_mean = samples.mean(axis=0)
    g_se = samples.std(axis=0, ddof=1) / np.sqrt(len(samples))
    rv_rep = _relvar(samples[:, 1])
    f_mean, f_se, m_var = m.estimate()
    exact = np.array(m.exact)
    m_mean, m_se = exact.mean(axis=0), exact.std(axis=0, ddof=1) / np.sqrt(len(exact))
    rv_m = m_var[1] / f_mean[1] ** 2
    print(f"{name}: Mitsuba {np.median(m.seconds):.3f} s per render ({SPP} spp, "
          f"{m.weights.size} px cropped, {len(m.seconds)} renders), rel. sd of G "
          f"{np.sqrt(rv_m) * 100:.3f} %; {traces[0]:.2f} traces and {traces[1]:.1f} rays per "
          f"grassd path at 21 lengths; grassd's variance from {len(samples)} replicates")
    for label, (reps, g) in runs.items():
        rv = rv_rep / reps
        print(f"{name}, {label}: grassd {RenderSettings().samples} paths x {reps} replicates, "
              f"one length {np.median(g['t1']):.3f} s, 21 lengths {np.median(g['t21']):.3f} s "
              f"(rel. sd of G at {LENGTH_MM:g} mm {np.sqrt(rv) * 100:.3f} %)")
        _efficiencies(name, label, g, rv, m, rv_m)
    diff = (g_mean - m_mean) / m_mean * 100
    z = (g_mean - m_mean) / np.sqrt(g_se ** 2 + m_se ** 2)
    prec = np.sqrt(g_se ** 2 + m_se ** 2) / m_mean * 100
    agree = bool(np.all(np.abs(z) < 2.0))
    print(f"{name}: means grassd {np.round(g_mean, 3)} Mitsuba {np.round(m_mean, 3)} nits "
          f"(quad sampled exactly, {len(exact)} x {EXACT_RAYS} paths); difference R G B "
          f"{np.round(diff, 3)} % = {np.round(z, 2)} combined SE (SE {np.round(prec, 3)} %): "
          f"{'agree' if agree else 'DIFFER'} within 2 SE")
    fdiff = (g_mean - f_mean) / f_mean * 100
    fz = (g_mean - f_mean) / np.sqrt(g_se ** 2 + f_se ** 2)
    print(f"{name}: Mitsuba's coverage-weighted film instead: difference {np.round(fdiff, 3)} % "
          f"= {np.round(fz, 2)} SE (partly covered pixels carry light from outside the quad)")


def _replicates_at_noise(m: MitsubaSide, call, one: np.ndarray) -> int:
    """grassd's replicates (of its default paths per replicate) whose one-length G is about as
    noisy as one Mitsuba render: untimed pilots of both sides (:data:`PILOT_RENDERS` renders,
    :data:`PILOT_SEEDS`; 96 replicates, so the count is good to about +-15 %). Says so where
    the count is capped at MAX_REPLICATES."""
    from grassd.sim.scene import MAX_REPLICATES, RenderSettings

    rv_m = m.pilot_relvar()
    g_reps = np.concatenate([call(one, RenderSettings(seed=s)).rgb_replicates[:, 0, 1]
                             for s in PILOT_SEEDS])
    need = int(np.ceil(_relvar(g_reps) / rv_m))
    if need > MAX_REPLICATES:
        print(f"grassd would need {need} replicates to match Mitsuba's noise; "
              f"taking {MAX_REPLICATES}, so its row 'at Mitsuba's noise' is noisier than that")
    return int(np.clip(need, 2, MAX_REPLICATES))


def run_scene(name: str, rounds: int, renderer) -> None:
    """Interleave ``rounds`` rounds of Mitsuba renders and grassd calls on one panorama: grassd
    at its defaults and at Mitsuba's noise (more replicates), each at one and 21 lengths."""
    from grassd.sim.export import export_scene
    from grassd.sim.lighting import build_lighting
    from grassd.sim.scene import DisplaySpec, RenderSettings, Viewpoint

    display, vp = DisplaySpec(), Viewpoint(170, 2, 0)
    lighting = build_lighting(HDRI_DIR / f"{name}.exr", LUX)
    with tempfile.TemporaryDirectory() as tmp:
        export_scene(tmp, display, lighting, vp, LENGTH_MM, RenderSettings(max_bounces=3))
        mits = MitsubaSide(Path(tmp))
    one = np.array([LENGTH_MM])
    k10 = int(np.argmin(np.abs(LENGTHS_MM - LENGTH_MM)))

    def call(lengths: np.ndarray, settings):
        return renderer.characteristic(display, lighting, vp, lengths, settings)

    for lengths in (LENGTHS_MM, one):  # scene built for 20 mm, both kernels compiled: untimed
        call(lengths, RenderSettings(samples=64, replicates=2))
    # label: replicates, seed offset (the defaults keep grassd's seeds of earlier runs)
    labels = {"defaults": (RenderSettings().replicates, 0),
              "at Mitsuba's noise": (_replicates_at_noise(mits, call, one), 100_000)}
    times: dict[str, dict[str, list[float]]] = {
        label: {k: [] for k in ("t1", "c1", "t21", "c21")} for label in labels}
    samples, traces = [], []
    for r in range(rounds):
        for _ in range(RENDERS_PER_ROUND):
            mits.render()
        mits.measure_exact()
        for label, (reps, offset) in labels.items():
            g = times[label]
            for key, lengths, seed, k in (("1", one, 1000 + r, 0), ("21", LENGTHS_MM, r, k10)):
                time.sleep(SETTLE_S)
                c0 = time.process_time()
                res = call(lengths, RenderSettings(seed=seed + offset, replicates=reps))
                g["c" + key].append(time.process_time() - c0)
                g["t" + key].append(res.seconds["trace"])
                samples.append(res.rgb_replicates[:, k])
            traces.append((res.paths_traced / res.samples_per_length,
                           res.rays_traced / res.samples_per_length))
    runs = {label: (reps, times[label]) for label, (reps, _) in labels.items()}
    _summary(name, np.concatenate(samples), runs, mits, tuple(np.mean(traces, axis=0)))


def main() -> None:
    reason = _skip_reason()
    if reason:
        print(f"bench mitsuba skipped: {reason}")
        return
    import mitsuba as mi

    from grassd.sim import backend
    from grassd.sim.renderer import Renderer

    mi.set_variant("llvm_ad_rgb")
    backend.init(os.environ.get("GRASSD_BENCH_ARCH", "cpu"))
    renderer = Renderer.shared()
    rounds = int(os.environ.get("GRASSD_BENCH_MITSUBA_ROUNDS", "10"))
    names = os.environ.get("GRASSD_BENCH_MITSUBA_SCENES", "courtyard,forest").split(",")
    print(f"Mitsuba {mi.__version__} llvm_ad_rgb (libLLVM {os.environ['DRJIT_LIBLLVM_PATH']}),"
          f" {os.cpu_count()} CPU cores, {rounds} interleaved rounds")
    for name in names:
        run_scene(name.strip(), rounds, renderer)


if __name__ == "__main__":
    main()
