"""Benchmarks of the calib hot paths; prints timings, asserts nothing.

Run: ``.venv/bin/python -m bench.bench_calib``
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np
from colour import delta_E

from grassd.calib.characteristic import Characteristic, fit_characteristic
from grassd.calib.colour_spaces import rec709_to_xyz
from grassd.calib.compare import discrete_frechet
from grassd.calib.dng import DngCamera, write_linear_dng
from grassd.calib.length_table import build_length_table
from grassd.calib.ogcd import ogcd_from_rgb
from grassd.calib.raw import develop_raw
from grassd.calib.regions import extract_checker_patches, quad_mean


def _time(label: str, fn, repeat: int = 3) -> float:
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    print(f"{label:<55s} {best * 1e3:10.2f} ms")
    return best


def main() -> None:
    rng = np.random.default_rng(0)
    n = 1_000_000
    a = np.column_stack([rng.uniform(0, 100, n), rng.uniform(-100, 100, (n, 2))])
    b = a + rng.normal(0, 5, a.shape)
    t = _time(f"CIEDE2000, {n:,} pairs", lambda: delta_E(a, b))
    print(f"{'':<55s} {n / t / 1e6:10.2f} M pairs/s")

    img = rng.uniform(0, 1, (3000, 4500, 3)).astype(np.float32)
    quad = [(400.0, 300.0), (4100.0, 500.0), (3900.0, 2700.0), (600.0, 2600.0)]
    _time("quad_mean, 3000x4500 image, ~8 Mpx quadrilateral", lambda: quad_mean(img, quad))
    _time("extract_checker_patches, 24 patches", lambda: extract_checker_patches(img, quad))

    x = np.linspace(0, 20, 201)
    rgb = np.column_stack([0.4 - 0.015 * x, 0.3 - 0.005 * x, 0.1 - 0.003 * x])
    se = np.full_like(rgb, 0.002)
    _time("ogcd_from_rgb with stderr, 201 lengths", lambda: ogcd_from_rgb(rgb, se))

    y = 12 / (1 + np.exp(-(x - 11) / 1.5))
    y = np.clip(y - y[0] + rng.normal(0, 0.3, x.size), 0, None)
    char = Characteristic(x, y)
    _time(
        "fit + 8-bit table, 201 noisy points", lambda: build_length_table(fit_characteristic(char))
    )

    p = rng.normal(size=(2000, 2)).cumsum(axis=0)
    q = rng.normal(size=(2000, 2)).cumsum(axis=0)
    _time("discrete Frechet, 2000 x 2000 points", lambda: discrete_frechet(p, q), repeat=1)

    with tempfile.TemporaryDirectory() as tmp:
        xyz = rec709_to_xyz(rng.uniform(0.05, 0.6, (1000, 1500, 3)))
        path = write_linear_dng(Path(tmp) / "bench.dng", xyz, DngCamera())
        _time("develop_raw, 1000x1500 DNG (LibRaw AHD, ProPhoto 16 bit)", lambda: develop_raw(path))


if __name__ == "__main__":
    main()
