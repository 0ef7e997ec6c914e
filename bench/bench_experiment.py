"""Benchmarks of validate / the paper experiment; prints timings beside the paper's, asserts
nothing.

Run: ``.venv/bin/python -m bench.bench_experiment [--full] [--arch gpu]``

* the paper's per-viewpoint simulation (21 lengths 0..20 mm, 4096 paths x 8 replicates) and
  the 16 viewpoints (paper Table 1: about 5 s per viewpoint, 80 s for 16, on an RTX 4070);
* the virtual camera (render a 160 px view at 32 spp, expose, write the DNG) and the real side
  of validate (rawpy development + quad mean) per photo;
* with ``--full``: ``grassd experiment paper`` at its default sizes (CPU: several minutes).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from bench import HDRI_DIR

#: the paper environments' HDRIs: ``shared/hdri`` beside the repository


def main(argv: list[str] | None = None) -> None:
    """Run the benchmarks (``argv``: command-line flags; None = defaults, as ``python -m
    bench`` calls it)."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--full", action="store_true", help="also run experiment paper (minutes)")
    ap.add_argument("--arch", default="cpu", choices=["cpu", "gpu"])
    args = ap.parse_args([] if argv is None else argv)

    from grassd.daemon.core.calibration.simulation import simulate_curve
    from grassd.daemon.offline.experiment import (
        PAPER,
        VIEWPOINTS,
        ExperimentSettings,
        run_paper,
        text_report,
    )
    from grassd.daemon.offline.validate import load_manifest, measure_real
    from grassd.daemon.offline.virtual_capture import capture_world
    from grassd.sim import backend
    from grassd.sim.light_input import LightInput
    from grassd.sim.scene import DisplaySpec, RenderSettings, Viewpoint

    backend.init(args.arch)
    from grassd.sim.renderer import Renderer

    renderer = Renderer.shared()
    light = LightInput(HDRI_DIR / "interior.exr", 500.0)
    lighting = light.lighting()
    lengths = np.arange(0.0, 20.01, 1.0)
    settings = RenderSettings(samples=4096, replicates=8)
    display = DisplaySpec()
    simulate_curve(renderer, display, lighting, Viewpoint(), lengths[:3],
                   RenderSettings(samples=64, replicates=2))  # compile / load the kernel
    t0 = time.perf_counter()
    per = []
    for vp in VIEWPOINTS:
        t = time.perf_counter()
        simulate_curve(renderer, display, lighting, Viewpoint(*vp), lengths, settings)
        per.append(time.perf_counter() - t)
    total = time.perf_counter() - t0
    paths = 21 * settings.strata ** 2 * settings.replicates
    print(f"simulate one viewpoint (21 lengths, {paths:,} samples) "
          f"{np.mean(per):8.2f} s  (paper: about {PAPER['seconds_per_viewpoint']:g} s)")
    print(f"simulate 16 viewpoints                                  {total:8.2f} s  "
          f"(paper: about {PAPER['seconds_16_viewpoints']:g} s; manual: about 80 min)")
    print(f"  throughput                                            "
          f"{paths * len(VIEWPOINTS) / total / 1e6:8.2f} M samples/s (path x length)")

    with tempfile.TemporaryDirectory() as tmp:
        n = 6
        t = time.perf_counter()
        capture_world(Path(tmp), light, [(170.0, 2.0, 0.0)], lengths[:: 21 // n][:n],
                      renderer=renderer, lighting=lighting, width=160, spp=32)
        dt = time.perf_counter() - t
        print(f"virtual camera: render 160 px x 32 spp + DNG, per photo {dt / n:8.2f} s")
        m = load_manifest(tmp)
        t = time.perf_counter()
        measure_real(m)
        dt = time.perf_counter() - t
        print(f"validate real side: develop + measure, per RAW        {dt / (n + 1):8.3f} s")

    if args.full:
        with tempfile.TemporaryDirectory() as tmp:
            res = run_paper(tmp, settings=ExperimentSettings(), hdri_dir=HDRI_DIR,
                            renderer=renderer)
            print(text_report(res))


if __name__ == "__main__":
    main(sys.argv[1:])
