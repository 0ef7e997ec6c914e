"""``grassd measure`` end to end: the embedded default config's 4 x 8 display on
simulated hardware, its pixels varied as tests/data/measure/secret_variation.toml says, measured
from test patterns to pushed per-pixel tables, as ``grassd measure --now --simulate-hardware
--sim-display-variation FILE`` runs it (one process, cold: renderer start, the simulated site,
the set-up shot, then the measurement).

Prints the command's wall time, the measurement's own time by phase (target: at most 5 min on
2 cores for patterns, photos, fit and tables), the recovered variation's correlation with the
truth per field, and the uniformity (worst pixel pair, dE00, at level 128) before and after.

With ``MEASURE_SPECTRAL=1`` (needs Mitsuba, the test extra) it measures the same display in a
world grassd did not render instead (:mod:`grassd.rigs.spectral_display`), once per camera
of ``MEASURE_CAMERAS`` (default the Nikon D5100 and the CIE observer's colorimetric camera):
the correlations, the worst pixel pair as the CIE observer sees it before, with the measured
correction and with the true variation corrected the same way, the set-up's checker
leave-one-out error, and the time.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from grassd.daemon.core.calibration.variation import load_variation

GRASSD = str(Path(sys.executable).parent / "grassd")
SECRET = Path(__file__).resolve().parents[1] / "tests" / "data" / "measure" / \
    "secret_variation.toml"


def main() -> None:
    with tempfile.TemporaryDirectory() as d:
        out = Path(d) / "out.json"
        t0 = time.perf_counter()
        run = subprocess.run([GRASSD, "measure", "--now", "--state-dir",
                              str(Path(d) / "state"), "--simulate-hardware",
                              "--sim-display-variation", str(SECRET), "--json", str(out)],
                             capture_output=True, text=True)
        wall = time.perf_counter() - t0
        if run.returncode != 0:
            print(f"grassd measure failed ({run.returncode}): {run.stderr[-1500:]}")
            return
        report = json.loads(out.read_text())
    truth = load_variation(SECRET, 32)
    s = report["seconds"]
    print(f"command wall {wall:.1f} s; measurement {s['total']:.1f} s (tables without "
          f"correction {s['calibrate']:.1f}, photos {s['photos_before']:.1f}, models + fit + "
          f"verification photos {s['analyse_and_after']:.1f}); goal <= 300 s")
    for f in ("length_offset_mm", "green_gain", "yellow_gain"):
        got = np.array([p[f] for p in sorted(report["pixels"], key=lambda p: p["index"])])
        err = got - getattr(truth, f)
        print(f"  {f:17s} r {np.corrcoef(got, getattr(truth, f))[0, 1]:.3f}  "
              f"rms error {np.sqrt(np.mean((err - err.mean()) ** 2)):.3f} (after the mean)")
    u = report["uniformity"]
    print(f"  worst pixel pair at level {u['level']}: {u['before']:.2f} -> {u['after']:.2f} "
          f"dE00 ({u['before'] / u['after']:.2f}x; goal >= 3x); verdict "
          f"{report['verdict']['state']}")
    print(f"  camera found at {report['camera']['position_m']} m (rms "
          f"{report['camera']['rms_deg']:.3f} deg); display colour balance "
          f"{report['display_colour_balance']}")


def spectral() -> None:
    from grassd.rigs.spectral_display import measure_spectral_world

    truth = load_variation(SECRET, 32)
    for camera in os.environ.get("MEASURE_CAMERAS", "nikon-d5100,cie-1931").split(","):
        with tempfile.TemporaryDirectory() as d:
            t0 = time.perf_counter()
            m = measure_spectral_world(d, truth, camera=camera)
            wall = time.perf_counter() - t0
        r = " / ".join(f"{m.correlation[f]:.3f}" for f in ("length_offset_mm", "green_gain",
                                                            "yellow_gain"))
        w, u = m.worst_pair, m.report["uniformity"]
        print(f"{camera}: r offset / green / yellow {r} (goal 0.9 / 0.9 / 0.8); the observer's "
              f"worst pair {w['before']:.2f} -> {w['measured']:.2f} (the truth corrected: "
              f"{w['truth']:.2f}; goal within 0.5); the camera's {u['before']:.2f} -> "
              f"{u['after']:.2f}; checker leave-one-out {m.checker_de00[0]:.2f} / "
              f"{m.checker_de00[1]:.2f}; {wall:.0f} s (measurement "
              f"{m.report['seconds']['total']:.0f} s)")


if __name__ == "__main__":
    if os.environ.get("MEASURE_SPECTRAL"):
        spectral()
    else:
        main()
