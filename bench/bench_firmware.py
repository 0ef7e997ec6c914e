"""Benchmark: the C controller firmware (``firmware/``): motor loop, parser, power cuts, image size.

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

from grassd.rigs.native_build import BUILD_DIR, build_firmware
from grassd.rigs.power_cut import power_cut_sweep


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


def cortex_m7_byte_cost() -> None:
    """Instructions the Cortex-M7 image spends on its costliest received byte, counted under
    ``qemu-system-arm -icount shift=0`` (1 instruction = 1 ns of virtual time, SysTick at
    25 MHz: 40 instructions per count) over a session of every request type, a full per-pixel
    table push and garbage."""
    if shutil.which("qemu-system-arm") is None or shutil.which("arm-none-eabi-gcc") is None:
        print("Cortex-M7 byte cost: skipped, needs qemu-system-arm and arm-none-eabi-gcc")
        return
    from grassd.firmware_proto.client import ControllerClient, RetryPolicy
    from grassd.rigs.qemu_bus import QemuBus

    rng = np.random.default_rng(5)
    with tempfile.TemporaryDirectory() as tmp, \
            QemuBus(tmp, [1], n_pixels=16, qemu_args=["-icount", "shift=0"]) as bus, \
            ControllerClient(bus.path, policy=RetryPolicy(timeout_s=0.5)) as c:
        c.hello(1)
        c.read_status(1)
        c.push_table(1, rng.integers(0, 20001, (16, 256)))
        c.set_levels(1, list(range(0, 256, 16)))
        c.read_positions(1)
        with open(bus.path, "wb", buffering=0) as raw:  # garbage: dropped by the receiver
            raw.write(bytes(rng.integers(1, 256, 20000).astype(np.uint8)) + b"\x00")
        c.read_status(1)
        counts, kind = bus.controllers[0].worst_byte()
    names = {1: "HELLO", 2: "GET_STATUS", 3: "TABLE_BEGIN", 4: "TABLE_CHUNK", 5: "TABLE_COMMIT",
             6: "SET_LEVEL", 7: "GET_POSITIONS"}
    insns = counts * 40
    print(f"Cortex-M7 (QEMU mps2-an500, -icount shift=0): costliest received byte "
          f"{insns} instructions (the byte completing a {names.get(kind, kind)} of 16 "
          f"per-pixel tables) = {insns / 600:.0f} us at 600 MHz and 1 instruction per cycle; "
          f"the PD loop runs from SysTick above it, period 1000 us")


def main() -> None:
    """Every firmware figure."""
    motor()
    fuzz()
    power_cut()
    arm_size()
    cortex_m7_byte_cost()


if __name__ == "__main__":
    main()
    sys.exit(0)
