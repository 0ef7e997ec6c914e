"""Capture station round trip: the simulated OSC camera (real HTTP on 127.0.0.1) photographs
the site map with response curves the merge never sees; prints the merge's accuracy and time."""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np

from grassd.calib.hdr_merge import merge_ldr, recover_response, relative_exposure
from grassd.daemon.hardware.bracket import BracketPlan, capture_bracket, load_codes
from grassd.daemon.hardware.camera import OscClient
from grassd.daemon.hardware.simulated_camera import CURVES, SimCamera, site_hdri
from grassd.sim.hdri import REC709_LUMINANCE, downsample, load_hdri
from grassd.sim.lighting import horizontal_illuminance
from grassd.sim.sun import find_sun


def main() -> None:
    env = load_hdri(site_hdri())
    env = downsample(env, env.shape[1] // 256) if env.shape[1] > 256 else env
    plan = BracketPlan(shots=9, ev_step=2.0, centre_shutter_s=0.01)
    lum_src = env.astype(np.float64) @ REC709_LUMINANCE
    print(f"{'curve':8s} {'shots':>5s} {'capture s':>9s} {'response s':>10s} {'merge s':>7s} "
          f"{'med lum err':>11s} {'E err':>6s} {'sun deg':>7s}")
    for curve in CURVES:
        with SimCamera(env, scene_scale=80.0, curve=curve, seed=7) as cam, \
                tempfile.TemporaryDirectory() as d:
            t0 = time.perf_counter()
            shots = capture_bracket(OscClient(cam.url, poll_s=0.02), plan, Path(d))
            codes = load_codes(shots)
            t1 = time.perf_counter()
        h = [relative_exposure(s.exposure_s, s.iso, s.f_number) for s in shots]
        resp = recover_response(codes, h)
        t2 = time.perf_counter()
        m = merge_ldr(codes, h, resp)
        t3 = time.perf_counter()
        lum = m.radiance.astype(np.float64) @ REC709_LUMINANCE
        ok = ~m.clipped & (lum_src > 0)
        k = float(np.median(lum_src[ok] / lum[ok]))
        err = float(np.median(np.abs(lum[ok] * k / lum_src[ok] - 1)))
        e_err = abs(horizontal_illuminance(m.radiance * k) / horizontal_illuminance(env) - 1)
        a, b = find_sun(env), find_sun(m.radiance)
        sun = float(np.degrees(np.arccos(np.clip(a.direction @ b.direction, -1, 1))))
        print(f"{curve:8s} {len(shots):5d} {t1 - t0:9.2f} {t2 - t1:10.2f} {t3 - t2:7.3f} "
              f"{100 * err:10.2f}% {100 * e_err:5.2f}% {sun:7.3f}")
    print("targets: median |rel. luminance error| <= 3 %, E within 2 %, sun within 1 deg")
