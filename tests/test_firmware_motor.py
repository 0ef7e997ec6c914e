"""Motors: the core's PD loop (1 ms period) on the DC-motor model of the posix port (inertia,
Coulomb and static friction, backlash, 12.5 um encoder) moves a pixel 0 -> 20 mm and settles
within +-0.1 mm in <= 1 s with <= 0.2 mm overshoot, measured on the grass after the backlash."""

from __future__ import annotations

import json
import subprocess

import pytest
from firmware_util import missing_reason

from grassd.firmware_proto.native_build import build_firmware

pytestmark = pytest.mark.skipif(missing_reason("posix") is not None,
                                reason=str(missing_reason("posix")))


def test_full_step_settles_fast_without_overshoot():
    exe = build_firmware("build/bench_motor", "bench_motor")
    proc = subprocess.run([str(exe), "--json"], capture_output=True, text=True, timeout=60)
    res = json.loads(proc.stdout)
    full = res["steps"][0]
    assert (full["from_mm"], full["to_mm"]) == (0.0, 20.0)
    assert full["settle_s"] <= 1.0 and full["overshoot_mm"] <= 0.2
    assert proc.returncode == 0 and res["ok"]
    # every other step (down, half, small) settles too and ends inside the band
    for s in res["steps"]:
        assert s["settle_s"] <= 1.0 and s["overshoot_mm"] <= 0.2, s
        assert abs(s["final_error_mm"]) < 0.1, s
