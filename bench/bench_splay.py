"""The studio's splayed characteristic: traces, rays and wall time per launch set.

The studio's pixel (``resolve_config(None, None)``, the centre of its 3x3 patch), courtyard
5000 lx, viewpoint (170, 2, 5), 11 lengths 0..20 mm, warm kernels, launches of at least 2048
paths as the studio runs them: splay 8 deg with 16 x 256 paths (a studio round), and the same
pixel without splay with 4 x 1024 paths; then, under bench_studio's low sun (its slowest
change, :data:`bench.bench_studio.LOW_SUN`, lit as the studio lights it), both with 2 x 8192
paths, the settings of the larger replicates a run takes there
(:class:`~grassd.daemon.core.calibration.simulation.LargerReplicates`) and whole replicates a
launch, as the simulator process launches them. Prints the median of ``GRASSD_BENCH_SPLAY_RUNS``
(default 6) runs, traces and rays per camera path. Asserts nothing.

Run: ``python -m bench splay``. For an A/B against an older renderer, set
``GRASSD_BENCH_SPLAY_OLD`` to a copy of its ``sim/renderer.py``: both run interleaved in one
process (each Renderer compiles its own kernels).
"""

from __future__ import annotations

import importlib.util
import os
import statistics
import time
from dataclasses import replace

import numpy as np

from bench import COURTYARD
from bench.bench_studio import LOW_SUN

RUNS = int(os.environ.get("GRASSD_BENCH_SPLAY_RUNS", "6"))


def main() -> None:
    from grassd.daemon.core.calibration.calibrate import Calibrator
    from grassd.daemon.core.calibration.simulation import LargerReplicates
    from grassd.daemon.core.config.settings import resolve_config
    from grassd.daemon.studio.lights import Lights, LightSource
    from grassd.daemon.studio.pace import STUDIO_LAUNCH_PATHS
    from grassd.daemon.studio.session import Studio
    from grassd.sim import renderer as current
    from grassd.sim.backend import init
    from grassd.sim.hdri import load_hdri
    from grassd.sim.lighting import build_lighting
    from grassd.sim.scene import RenderSettings, Viewpoint

    init("cpu")
    renderers = {"current": current.Renderer()}
    old = os.environ.get("GRASSD_BENCH_SPLAY_OLD")
    if old:
        spec = importlib.util.spec_from_file_location("renderer_old", old)
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        renderers["old"] = module.Renderer()
    for r in renderers.values():
        r.min_launch_paths = STUDIO_LAUNCH_PATHS  # the studio's (also on an older renderer)
    display, centre = Calibrator(resolve_config(None, None)).display()
    light = build_lighting(load_hdri(COURTYARD), ambient_lux=5000)
    studio = Studio(resolve_config(None, None), Lights([LightSource("file", "c", COURTYARD)]))
    sun = studio.lights.lighting(studio.parse({"ambient_lux": 5000, "viewpoint": [170, 2, 5],
                                               "sun": LOW_SUN}), studio.site)
    larger = LargerReplicates()
    low_sun = {"light_samples": larger.light_samples, "roulette_from": larger.roulette_from}
    lengths = np.arange(0.0, display.pixel.green_max_mm + 1e-9, 2.0)
    cases = [("", light, 8.0, 256, 16, {}), ("", light, 0.0, 1024, 4, {}),
             (" in a low sun", sun, 8.0, larger.samples, 2, low_sun),
             (" in a low sun", sun, 0.0, larger.samples, 2, low_sun)]
    for where, lit, splay, samples, reps, extra in cases:
        d = replace(display, pixel=replace(display.pixel, splay_deg=splay))
        times: dict[str, list[float]] = {k: [] for k in renderers}
        last = {}
        for run in range(RUNS + 1):  # run 0 warms (compiles)
            names = list(renderers) if run % 2 else list(renderers)[::-1]
            for name in names:
                s = RenderSettings(samples=samples, replicates=reps, seed=run, **extra)
                t0 = time.perf_counter()
                last[name] = renderers[name].characteristic(
                    d, lit, Viewpoint(170, 2, 5), lengths, s, pixel_index=centre)
                if run:
                    times[name].append(time.perf_counter() - t0)
        print(f"splay {splay:g} deg{where}, {len(lengths)} lengths x {reps} x {samples} paths:")
        for name, m in last.items():
            print(f"  {name}: {statistics.median(times[name]) * 1e3:.0f} ms median of {RUNS}, "
                  f"{m.paths_traced / m.samples_per_length:.2f} traces and "
                  f"{m.rays_traced / m.samples_per_length:.1f} rays a path")
        if "old" in last:
            a, b = last["current"].rgb_replicates, last["old"].rgb_replicates
            same = np.array_equal(a, b)
            print(f"  old == current: {same}" + ("" if same else
                  f" (largest relative difference {np.max(np.abs(a - b) / np.abs(b)):.2g}: "
                  "the kernels' compiled rounding, grazing rays)"))


if __name__ == "__main__":
    main()
