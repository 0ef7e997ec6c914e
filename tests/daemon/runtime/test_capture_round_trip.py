"""Capture from the simulated OSC camera (a real HTTP server on 127.0.0.1) and merge: the
merged map must reproduce the photographed HDRI, with response curves the merge never sees."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from grassd.calib.hdr_merge import merge_ldr, recover_response, relative_exposure
from grassd.daemon.camera.bracket import BracketPlan, capture_bracket, load_codes
from grassd.daemon.camera.client import OscClient
from grassd.rigs.simulated_camera import SimCamera
from grassd.sim.hdri import REC709_LUMINANCE, default_site_hdri, downsample, load_hdri
from grassd.sim.lighting import horizontal_illuminance
from grassd.sim.sun import find_sun

#: 9 shots 2 EV apart from 1/25000 s: the shortest holds the site map's sun at this light level
PLAN = BracketPlan(shots=9, ev_step=2.0, iso=100, centre_shutter_s=0.01, max_shutter_s=1.0)


def site_env() -> np.ndarray:
    env = load_hdri(default_site_hdri())
    return downsample(env, env.shape[1] // 256) if env.shape[1] > 256 else env


def round_trip(curve: str, tmp_path, seed: int) -> dict[str, float]:
    env = site_env()
    with SimCamera(env, scene_scale=80.0, curve=curve, seed=seed) as cam:
        client = OscClient(cam.url, timeout_s=5, command_timeout_s=10, poll_s=0.02)
        shots = capture_bracket(client, PLAN, tmp_path / curve)
        codes = load_codes(shots)
    h = [relative_exposure(s.exposure_s, s.iso, s.f_number) for s in shots]
    merged = merge_ldr(codes, h, recover_response(codes, h))
    lum_src = env.astype(np.float64) @ REC709_LUMINANCE
    lum = merged.radiance.astype(np.float64) @ REC709_LUMINANCE
    ok = ~merged.clipped & (lum_src > 0)
    scale = float(np.median(lum_src[ok] / lum[ok]))  # the one unknown: the camera's gain
    err = np.abs(lum[ok] * scale / lum_src[ok] - 1.0)
    e_src = horizontal_illuminance(env)
    e_merged = horizontal_illuminance(merged.radiance * scale)
    sun_src, sun = find_sun(env), find_sun(merged.radiance)
    assert sun_src is not None and sun is not None
    angle = np.degrees(np.arccos(np.clip(sun_src.direction @ sun.direction, -1, 1)))
    return {"median_rel_err": float(np.median(err)), "clipped": merged.clipped_fraction,
            "illuminance_err": abs(e_merged / e_src - 1.0), "sun_deg": float(angle),
            "shots": len(shots)}


@pytest.mark.parametrize("curve", ["filmic", "soft"])
def test_round_trip_through_the_simulated_camera(curve, tmp_path):
    m = round_trip(curve, tmp_path, seed=3)
    print(f"\n{curve}: {m['shots']} shots, median |rel. luminance error| "
          f"{100 * m['median_rel_err']:.2f} %, horizontal illuminance error "
          f"{100 * m['illuminance_err']:.2f} %, sun found {m['sun_deg']:.3f} deg off, "
          f"clipped {100 * m['clipped']:.3f} %")
    assert m["median_rel_err"] <= 0.03
    assert m["illuminance_err"] <= 0.02
    assert m["sun_deg"] <= 1.0


def test_two_curves_recover_two_responses(tmp_path):
    """The merge learns each camera's own curve from its shots (never handed the curve)."""
    env = site_env()
    responses = []
    for curve in ("filmic", "gamma22"):
        with SimCamera(env, scene_scale=80.0, curve=curve, seed=1) as cam:
            client = OscClient(cam.url, timeout_s=5, poll_s=0.02)
            shots = capture_bracket(client, PLAN, tmp_path / curve)
            codes = load_codes(shots)
        h = [relative_exposure(s.exposure_s, s.iso, s.f_number) for s in shots]
        responses.append(recover_response(codes, h)[:, 1])
    # the two inverse responses differ where the curves do (mid-dark codes)
    assert abs(np.log(responses[0][60] / responses[1][60])) > 0.1


def test_raw_bracket_merges_linearly(tmp_path):
    """RAW+ (as a THETA Z1): the DNGs of the bracket are developed by rawpy and merged
    linearly, without any response."""
    from grassd.calib.hdr_merge import merge_linear
    from grassd.calib.raw_bracket import develop_bracket

    env = site_env()
    plan = dataclasses.replace(PLAN, file_format="raw+")  # the shortest holds the sun
    with SimCamera(env, scene_scale=80.0, seed=5) as cam:
        shots = capture_bracket(OscClient(cam.url, poll_s=0.02), plan, tmp_path)
    assert all(s.raw_path is not None and s.raw_path.suffix == ".dng" for s in shots)
    h = [relative_exposure(s.exposure_s, s.iso, s.f_number) for s in shots]
    merged = merge_linear(develop_bracket([s.raw_path for s in shots]), h)
    lum_src = env.astype(np.float64) @ REC709_LUMINANCE
    lum = merged.radiance.astype(np.float64) @ REC709_LUMINANCE
    ok = ~merged.clipped & (lum_src > 0)
    scale = float(np.median(lum_src[ok] / lum[ok]))
    err = float(np.median(np.abs(lum[ok] * scale / lum_src[ok] - 1.0)))
    e_err = abs(horizontal_illuminance(merged.radiance * scale) / horizontal_illuminance(env)
                - 1.0)
    print(f"\nraw+: {len(shots)} shots, median |rel. luminance error| {100 * err:.2f} %, "
          f"horizontal illuminance error {100 * e_err:.2f} %")
    assert merged.method == "linear"
    assert err <= 0.03 and e_err <= 0.02
