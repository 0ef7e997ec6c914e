"""Benchmark: the C controller firmware (``firmware/``), every figure issue #15 asks for.

Prints: the motor step response (PD loop on the DC-motor model: settling time into +-0.1 mm
and overshoot), the fuzz run's count of frames and the time one received byte costs (worst
case, against the 1 ms motor loop period), the number of power-cut points tested over a table
update, and ``arm-none-eabi-size`` of the Cortex-M7 image when the ARM toolchain is present.

Run: ``python -m bench firmware`` or ``python bench/bench_firmware.py``.
"""

from __future__ import annotations

import shutil
import subprocess
import sys
import tempfile

import numpy as np

from grassd.firmware_proto.native_build import BUILD_DIR, build_firmware
from grassd.firmware_proto.power_cut import power_cut_sweep


def motor() -> None:
    """Step responses of the PD loop (bench_motor prints gains, plant and figures)."""
    exe = build_firmware("build/bench_motor", "bench_motor")
    print(subprocess.run([str(exe)], capture_output=True, text=True, check=False).stdout, end="")


def fuzz() -> None:
    """10^6 frames through the core without sanitizers, timing each frame's last byte."""
    exe = build_firmware("build/fuzz_timing", "fuzz_timing")
    print(subprocess.run([str(exe), "1000000", "7"], capture_output=True, text=True,
                         check=False).stdout, end="")


def power_cut() -> None:
    """Cut points over a per-pixel table update (16 pixels, 256-byte chunks)."""
    rng = np.random.default_rng(1)
    old = rng.integers(0, 20001, 256).astype(np.uint16)
    new = rng.integers(0, 20001, (16, 256)).astype(np.uint16)
    keeps = ("none", "half", "all-but-one")
    with tempfile.TemporaryDirectory() as tmp:
        out = power_cut_sweep(tmp, old, new, n_pixels=16, max_chunk=256, keeps=keeps)
    cuts = [o for o in out if o.cut]
    writes = len(cuts) // len(keeps)
    ok = all(o.active in ("old", "new") and o.status_crc_ok and o.recovered for o in out)
    print(f"power cut: {len(cuts)} cut points tested ({writes} storage writes: BEGIN, "
          f"{writes - 2} chunks, COMMIT; each torn 3 ways: none, half, all but one byte "
          f"landed) + {len(keeps)} uncut runs; after each restart: "
          f"{sum(o.active == 'old' for o in out)} x old table, "
          f"{sum(o.active == 'new' for o in out)} x new, "
          f"{sum(o.active == 'mix' for o in out)} x mix; all CRCs valid: {ok}")


def arm_size() -> None:
    """arm-none-eabi-size of the Cortex-M7 image (mps2-an500) and of the core alone."""
    if shutil.which("arm-none-eabi-gcc") is None:
        print("arm size: skipped, arm-none-eabi-gcc not on PATH (apt-get install "
              "gcc-arm-none-eabi libnewlib-arm-none-eabi)")
        return
    build_firmware("arm", "mps2/grassfw-mps2.elf")
    print((BUILD_DIR / "mps2" / "size.txt").read_text(), end="")


def main() -> None:
    """Every firmware figure."""
    motor()
    fuzz()
    power_cut()
    arm_size()


if __name__ == "__main__":
    main()
    sys.exit(0)
