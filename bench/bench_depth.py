"""Path depth benchmark: what the ``max_bounces`` cut costs in colour and what depth costs in time.

For a pale pink pixel (indoor light) and a dark green one (courtyard), one viewpoint, 21 lengths:
the colour (CIELAB, a white horizontal card as Y = 1) with paths cut at each depth against a
deep reference (:data:`DEEP` bounces, Russian roulette alone ends the paths in practice), in
CIEDE2000, at 0, 10 and 20 mm and the worst length, with the standard error of each difference
(the replicates' spread); the characteristic (OGCD: CIEDE2000 to 0 mm) likewise; and the warm
21-length trace's time at the cut and without it. Prints numbers, asserts nothing.

With ``DEPTH_MITSUBA=1`` (needs the test extra and libLLVM >= 16) it measures instead how far
the quad's mean radiance agrees with Mitsuba 3's path tracer at matched settings (grassd's
``max_bounces`` n against Mitsuba's ``max_depth`` n + 1, no Russian roulette on Mitsuba's side),
at 3 bounces and at :data:`DEEP`, courtyard 5000 lx, (170, 2, 0), 10 mm, for the default pixel
and the pink one.

Run: ``python -m bench.bench_depth`` (2 CPU cores: about 2 minutes; the Mitsuba part about 10).
"""

from __future__ import annotations

import math
import os
import time
from pathlib import Path

import numpy as np
from colour import delta_E

from bench import HDRI_DIR
from grassd.calib.colour_spaces import prophoto_to_lab, rec709_to_prophoto
from grassd.sim.hdri import default_site_hdri
from grassd.sim.scene import MAX_BOUNCES, DisplaySpec, PixelSpec, RenderSettings, Viewpoint

DEEP = MAX_BOUNCES  #: the reference's bounces (a path reaches it with probability 2^-62)
CUTS = (1, 2, 3, 4, 5, 6, 8, 10, 12)
LENGTHS = np.arange(0.0, 20.01, 1.0)
VIEW = Viewpoint(170, 2, 0)

#: name: (pixel, HDRI of ../shared/hdri, ambient lux)
PIXELS: dict[str, tuple[PixelSpec, str, float]] = {
    "pink": (PixelSpec(yellow_srgb=(225.0, 200.0, 205.0), green_srgb=(235.0, 140.0, 185.0),
                       base_srgb=(215.0, 185.0, 195.0)), "interior", 500.0),
    "dark green": (PixelSpec(yellow_srgb=(70.0, 95.0, 40.0), green_srgb=(30.0, 70.0, 25.0),
                             base_srgb=(50.0, 65.0, 30.0)), "courtyard", 8000.0),
}


def _hdri(name: str) -> Path:
    path = HDRI_DIR / f"{name}.exr"
    return path if path.exists() else default_site_hdri()


def lab_of(rgb_nits: np.ndarray, lux: float) -> np.ndarray:
    """CIELAB of radiance (nits), a white horizontal Lambertian card (lux / pi nits) as Y = 1."""
    return prophoto_to_lab(rec709_to_prophoto(np.clip(rgb_nits, 0.0, None) * math.pi / lux))


def de_and_se(a: np.ndarray, b: np.ndarray, lux: float) -> tuple[np.ndarray, np.ndarray]:
    """CIEDE2000 between the replicate means ``a``, ``b`` ((R, n, 3) each), and its standard
    error from a jackknife over the replicates (the two runs' replicates are independent)."""
    de = delta_E(lab_of(a.mean(0), lux), lab_of(b.mean(0), lux))
    r = len(a)
    jack = np.array([delta_E(lab_of(np.delete(a, k, 0).mean(0), lux),
                             lab_of(np.delete(b, k, 0).mean(0), lux)) for k in range(r)])
    se = np.sqrt((r - 1) / r * ((jack - jack.mean(0)) ** 2).sum(0))
    return de, se


def ogcd(rep: np.ndarray, lux: float) -> np.ndarray:
    """OGCD (CIEDE2000 of each length to the first) of the replicates' mean."""
    lab = lab_of(rep.mean(0), lux)
    return delta_E(lab[:1], lab)


def mitsuba_agreement(rounds: int = 4) -> None:
    """grassd - Mitsuba of the quad's mean radiance, in % and in combined standard errors."""
    import tempfile

    from grassd.rigs.mitsuba_scene import configure_llvm, quad_mean, scene_dict
    from grassd.sim import backend
    from grassd.sim.export import export_scene
    from grassd.sim.lighting import build_lighting
    from grassd.sim.renderer import Renderer

    if not configure_llvm():
        print("Mitsuba agreement: needs libLLVM >= 16 (apt-get install libllvm19)")
        return
    import mitsuba as mi

    mi.set_variant("llvm_ad_rgb")
    backend.init("cpu")
    renderer = Renderer.shared()
    lighting = build_lighting(_hdri("courtyard"), 5000.0)
    x = np.array([10.0])
    for name, pixel in (("default", PixelSpec()), ("pink", PIXELS["pink"][0])):
        display = DisplaySpec(pixel)
        for bounces in (3, DEEP):
            settings = RenderSettings(samples=16384, replicates=64, max_bounces=bounces)
            ours = renderer.characteristic(display, lighting, VIEW, x, settings)
            with tempfile.TemporaryDirectory() as tmp:
                doc = export_scene(tmp, display, lighting, VIEW, 10.0, settings=settings)
                scene = mi.load_dict(scene_dict(tmp, 1, 64))
                t0 = time.perf_counter()
                ref = np.array([quad_mean(scene, doc, 1 << 20, seed) for seed in range(rounds)])
                t_mi = time.perf_counter() - t0
            mean = ref.mean(axis=0)
            se = np.hypot(ours.rgb_stderr[0], ref.std(axis=0, ddof=1) / math.sqrt(rounds))
            diff = ours.rgb_linear[0] - mean
            print(f"{name}, {bounces} bounces: grassd - Mitsuba = "
                  f"{np.round(diff / mean * 100, 3).tolist()} % "
                  f"({np.round(diff / se, 1).tolist()} SE; combined SE "
                  f"{np.round(se / mean * 100, 3).tolist()} %); Mitsuba {rounds} x 2^20 "
                  f"paths {t_mi:.0f} s, grassd {ours.seconds['trace']:.1f} s")


def main() -> None:
    from grassd.sim import backend
    from grassd.sim.lighting import build_lighting
    from grassd.sim.renderer import Renderer

    backend.init(os.environ.get("GRASSD_BENCH_ARCH", "cpu"))
    renderer = Renderer.shared()
    samples, reps = int(os.environ.get("DEPTH_SAMPLES", 4096)), int(os.environ.get(
        "DEPTH_REPLICATES", 16))
    for name, (pixel, hdri, lux) in PIXELS.items():
        lighting = build_lighting(_hdri(hdri), lux)
        display = DisplaySpec(pixel)

        def run(bounces: int, seed: int = 1, display=display, lighting=lighting):
            s = RenderSettings(samples=samples, replicates=reps, max_bounces=bounces, seed=seed)
            return renderer.characteristic(display, lighting, VIEW, LENGTHS, s)

        run(3)  # warm-up (JIT)
        deep = run(DEEP, seed=2)
        print(f"{name} ({hdri} {lux:g} lx, {VIEW.label()}), deep reference {DEEP} bounces, "
              f"{samples} x {reps} paths")
        print("  cut  dE00@0  dE00@10  dE00@20  max(se)  dOGCD@20  rays/path")
        for cut in CUTS:
            m = run(cut)
            de, se = de_and_se(m.rgb_replicates, deep.rgb_replicates, lux)
            d_ogcd = ogcd(m.rgb_replicates, lux)[-1] - ogcd(deep.rgb_replicates, lux)[-1]
            worst = int(np.argmax(de))
            print(f"  {cut:3d}  {de[0]:6.3f}  {de[10]:7.3f}  {de[20]:7.3f}  "
                  f"{de[worst]:.3f}@{LENGTHS[worst]:g}({se[worst]:.3f})  {d_ogcd:+7.3f}  "
                  f"{m.rays_traced / m.paths_traced:6.2f}")
        m = run(DEEP, seed=1)
        de, se = de_and_se(m.rgb_replicates, deep.rgb_replicates, lux)
        print(f"  deep seed 1 vs seed 2 (noise): max dE00 {de.max():.3f} (se {se.max():.3f})")
        for bounces in (3, DEEP):  # the warm 21-length trace, default paths
            walls = []
            for seed in range(5):
                s = RenderSettings(samples=4096, replicates=8, max_bounces=bounces, seed=seed)
                t0 = time.perf_counter()
                renderer.characteristic(display, lighting, VIEW, LENGTHS, s)
                walls.append(time.perf_counter() - t0)
            print(f"  warm 21-length trace, 4096 x 8 paths, {bounces} bounces: median "
                  f"{np.median(walls):.3f} s (min {min(walls):.3f})")


if __name__ == "__main__":
    if os.environ.get("DEPTH_MITSUBA"):
        mitsuba_agreement()
    else:
        main()
