"""The capture station's default path as a round trip: the simulated OSC camera (real HTTP on
127.0.0.1) serves a panorama with ``grassd camera sim``'s defaults, a station with
``[capture]``'s defaults captures it with the scene's true horizontal illuminance as its lux, and
the merged map is compared with what the camera photographed (what a bundle of the default path
holds). ``bench/bench_capture.py`` prints it per shared HDRI; the capture tests assert its goals.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np

from grassd.daemon.camera.config import CaptureConfig
from grassd.daemon.capture.station import HDRI_NAME, Station
from grassd.rigs.simulated_camera import SIM_WIDTH, sim_camera_from_file
from grassd.sim.hdri import REC709_LUMINANCE, load_hdri
from grassd.sim.lighting import horizontal_illuminance

#: Goals of the round trip (fractions): median |luminance error|, horizontal illuminance error.
LUMINANCE_GOAL = 0.03
ILLUMINANCE_GOAL = 0.02


def round_trip_errors(reference: np.ndarray, radiance: np.ndarray,
                      excluded: np.ndarray | None = None) -> dict[str, float]:
    """Errors (fractions) of a merged map ``radiance`` (H, W, 3, any scale) against the
    ``reference`` radiance (H, W, 3, cd/m^2) the camera photographed: ``lum`` median
    |relative luminance error| with the map scaled to the reference's horizontal illuminance
    (as the daemon scales a bundle to its lux reading), ``gain_lum`` the same with the gain
    fitted as the median texel ratio, ``illuminance`` |E error| of the map with that gain.
    ``excluded`` (H, W) bool: texels left out of the medians (saturated ones)."""
    ls = reference.astype(np.float64) @ REC709_LUMINANCE
    lm = radiance.astype(np.float64) @ REC709_LUMINANCE
    ok = (ls > 0) & (lm > 0)
    if excluded is not None:
        ok &= ~excluded
    e_ref, e_map = horizontal_illuminance(reference), horizontal_illuminance(radiance)
    gain = float(np.median(ls[ok] / lm[ok]))
    return {"lum": float(np.median(np.abs(lm[ok] * (e_ref / e_map) / ls[ok] - 1.0))),
            "gain_lum": float(np.median(np.abs(lm[ok] * gain / ls[ok] - 1.0))),
            "illuminance": abs(e_map * gain / e_ref - 1.0)}


def default_path_round_trip(hdri: Path, work: Path, seed: int = 0) -> dict[str, Any]:
    """One capture of ``hdri`` through the default path (module docstring) into directory
    ``work``: :func:`round_trip_errors` plus ``width`` (texels served), ``shots``,
    ``exposures_s`` (s), ``sun_clipped`` and ``seconds`` (wall time of the capture)."""
    with sim_camera_from_file(hdri, width=SIM_WIDTH, seed=seed, latency_s=0.01) as cam:
        reference = cam.env.astype(np.float64) * cam.scene_scale
        station = Station(CaptureConfig(camera=cam.url), work / "inbox", work / "state")
        station.client.poll_s = 0.01
        (work / "inbox").mkdir(parents=True, exist_ok=True)
        t0 = time.perf_counter()
        out = station.capture(lux=horizontal_illuminance(reference))
        seconds = time.perf_counter() - t0
        c = out.manifest["capture"]
        saturated = cam.signal(min(c["exposures_s"]), c["iso"]).max(axis=2) >= 1.0
    errors = round_trip_errors(reference, load_hdri(out.bundle / HDRI_NAME), saturated)
    return {**errors, "width": reference.shape[1], "shots": len(c["exposures_s"]),
            "exposures_s": c["exposures_s"], "sun_clipped": c["sun_clipped"],
            "saturated": int(saturated.sum()), "seconds": seconds}
