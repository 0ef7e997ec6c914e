"""Taichi's GPU backend against the CPU backend on the same seeds: the GPU backend runs the same
kernels and must keep agreeing with the CPU. Prints numbers, asserts nothing.

Each arch renders in its own process (Taichi takes one arch per process): courtyard and forest
(the shared HDRIs; the bundled default site where they are missing) at 5000 lx, view
(170 cm, 2 m, 0 deg), 21 lengths 0..20 mm, seeds 0..SEEDS-1, the default settings (4096 paths x
8 replicates). The same seed draws the same random numbers on both, so the replicate means agree
to float rounding where no path takes another branch; where one does (a ray grazing a blade edge),
the two are still draws of one estimator. The comparison prints, per scene:

- the largest difference of the means over all lengths and channels, in % and in combined
  standard errors (both arches' replicate spreads);
- how many replicate means are bit-identical, and the largest relative difference of one;
- paths and rays traced (the per-ray memo's decisions) on each;
- trace time per length-path on each, after a warm-up launch.

Run: ``python -m bench backend`` (one line and no comparison where Taichi's ``gpu`` falls back
to the CPU; a software Vulkan driver, as on a machine without a GPU, counts as a GPU and takes
about 40 s), or one side alone: ``python -m bench.bench_backend --arch gpu --out gpu.npz``.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from bench import HDRI_DIR
from grassd.sim.hdri import default_site_hdri

BUNDLED = default_site_hdri()
SCENES = ("courtyard", "forest")
LUX = 5000.0
SEEDS = 4
LENGTHS_MM = np.arange(0.0, 20.01, 1.0)


def _hdri(name: str) -> Path:
    path = HDRI_DIR / f"{name}.exr"
    return path if path.exists() else BUNDLED


def render_side(arch: str, out: Path) -> str:
    """Render every scene and seed on ``arch``; save the replicate means (linear RGB, nits) and
    counters to ``out`` (npz). Returns the arch Taichi actually uses (``x64``, ``cuda``...)."""
    from grassd.sim import backend
    from grassd.sim.lighting import build_lighting
    from grassd.sim.renderer import Renderer
    from grassd.sim.scene import DisplaySpec, RenderSettings, Viewpoint

    actual = backend.init(arch)
    renderer = Renderer.shared()
    display, vp = DisplaySpec(), Viewpoint(170, 2, 0)
    arrays: dict[str, np.ndarray] = {"arch": np.array(actual)}
    for name in SCENES:
        lighting = build_lighting(_hdri(name), LUX)
        renderer.characteristic(display, lighting, vp, LENGTHS_MM[:3],
                                RenderSettings(samples=64, replicates=2))  # JIT, upload
        reps, counts, secs = [], [], []
        for seed in range(SEEDS):
            res = renderer.characteristic(display, lighting, vp, LENGTHS_MM,
                                          RenderSettings(seed=seed))
            reps.append(res.rgb_replicates)
            counts.append((res.paths_traced, res.rays_traced,
                           res.samples_per_length * len(LENGTHS_MM)))
            secs.append(res.seconds["trace"])
        arrays[f"{name}_reps"] = np.stack(reps)  # (seed, replicate, length, rgb)
        arrays[f"{name}_counts"] = np.array(counts, np.int64)
        arrays[f"{name}_trace_s"] = np.array(secs)
    np.savez(out, **arrays)
    return actual


def compare(cpu: dict, gpu: dict) -> None:
    """Print the agreement and speed of two :func:`render_side` outputs."""
    print(f"arches: {cpu['arch']} vs {gpu['arch']}")
    for name in SCENES:
        a, b = cpu[f"{name}_reps"], gpu[f"{name}_reps"]
        n_rep = a.shape[0] * a.shape[1]
        ma, mb = a.mean(axis=(0, 1)), b.mean(axis=(0, 1))
        se = np.sqrt(a.var(axis=(0, 1), ddof=1) / n_rep + b.var(axis=(0, 1), ddof=1) / n_rep)
        rel = (mb - ma) / ma
        z = (mb - ma) / se
        same = np.mean(np.all(a == b, axis=-1))
        rep_rel = np.abs(b - a) / np.abs(a)
        ca, cb = cpu[f"{name}_counts"].sum(axis=0), gpu[f"{name}_counts"].sum(axis=0)
        ta, tb = cpu[f"{name}_trace_s"], gpu[f"{name}_trace_s"]
        print(f"{name}: means over {n_rep} replicates x {len(LENGTHS_MM)} lengths: largest "
              f"difference {100 * np.abs(rel).max():.4f} % ({np.abs(z).max():.2f} SE; "
              f"{int((np.abs(z) > 2).sum())} of {z.size} beyond 2 SE); replicate means "
              f"bit-identical {100 * same:.1f} %, largest relative difference "
              f"{rep_rel.max():.2e}")
        print(f"{name}: traced paths {ca[0]} vs {cb[0]}, rays {ca[1]} vs {cb[1]} "
              f"(of {ca[2]} length-paths); trace per seed median {np.median(ta):.3f} s vs "
              f"{np.median(tb):.3f} s = {np.median(ta) / np.median(tb):.1f}x; "
              f"{ca[2] / len(ta) / np.median(tb) / 1e3:.0f} k length-paths/s on {gpu['arch']}")


def _side(arch: str, out: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "bench.bench_backend", "--arch", arch,
                           "--out", str(out)], capture_output=True, text=True, timeout=1200,
                          cwd=Path(__file__).resolve().parents[1])


def main() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        gpu = _side("gpu", Path(tmp) / "gpu.npz")
        if gpu.returncode != 0:
            print(f"bench backend: the GPU side failed (rc {gpu.returncode}):\n{gpu.stderr}")
            return
        g = dict(np.load(Path(tmp) / "gpu.npz"))
        if str(g["arch"]) in ("x64", "arm64"):
            print("bench backend skipped: Taichi found no GPU here (it fell back to the CPU)")
            return
        print(f"GPU side: {time.perf_counter() - t0:.1f} s with start-up and JIT")
        t0 = time.perf_counter()
        cpu = _side("cpu", Path(tmp) / "cpu.npz")
        if cpu.returncode != 0:
            print(f"bench backend: the CPU side failed (rc {cpu.returncode}):\n{cpu.stderr}")
            return
        print(f"CPU side ({os.cpu_count()} cores): {time.perf_counter() - t0:.1f} s with "
              f"start-up and JIT")
        compare(dict(np.load(Path(tmp) / "cpu.npz")), g)


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--arch", choices=["cpu", "gpu"])
    ap.add_argument("--out", type=Path)
    ns = ap.parse_args()
    if ns.arch and ns.out:
        print(render_side(ns.arch, ns.out))
    else:
        main()
