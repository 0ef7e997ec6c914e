"""Firmware backends for tests: ``pytest.param`` lists that run a test against the Python model
and the C firmware (posix process, QEMU image), skipping a tier whose tools are missing."""

from __future__ import annotations

import shutil
import subprocess

import pytest

from grassd.firmware_proto.client import RetryPolicy
from grassd.rigs.native_build import FIRMWARE_DIR

#: Why each firmware tier cannot run here, or None when it can.
_TOOLS = {
    "model": (),
    "posix": ("cc", "make"),
    "qemu": ("arm-none-eabi-gcc", "qemu-system-arm", "make"),
}
_HOW = {
    "posix": "posix firmware tier skipped: no C compiler/make (apt-get install gcc make)",
    "qemu": "QEMU firmware tier skipped: arm-none-eabi-gcc or qemu-system-arm not on PATH "
            "(apt-get install gcc-arm-none-eabi libnewlib-arm-none-eabi qemu-system-arm)",
}


def missing_reason(firmware: str) -> str | None:
    """One line saying how to enable the tier, or None when its tools are on PATH."""
    if all(shutil.which(t) for t in _TOOLS[firmware]):
        return None
    return _HOW[firmware]


#: What ``make -C firmware teensy41`` needs beyond make: the sketch is C++
TEENSY_PACKAGES = "gcc-arm-none-eabi libnewlib-arm-none-eabi libstdc++-arm-none-eabi-newlib"


def teensy_missing() -> str | None:
    """One line saying how to enable these tests, or None when `make teensy` can run here."""
    if shutil.which("make") is None:
        return f"Teensy 4.1 compile skipped: no make (apt-get install make {TEENSY_PACKAGES})"
    found = subprocess.run(["make", "-s", "--no-print-directory", "-C", str(FIRMWARE_DIR),
                            "have-teensy"], capture_output=True, text=True).stdout.strip()
    if not found:
        return ("Teensy 4.1 compile skipped: no arm-none-eabi-g++ with libstdc++ for the "
                f"Cortex-M7 (apt-get install {TEENSY_PACKAGES})")
    return None


def firmware_params(*names: str) -> list:
    """``pytest.param(name)`` per firmware, marked skip (one line) when its tools are missing."""
    out = []
    for n in names:
        reason = missing_reason(n)
        marks = [pytest.mark.skip(reason=reason)] if reason else []
        out.append(pytest.param(n, id=n, marks=marks))
    return out


#: For a test that asserts a clean link needs no retransmission. Every answer comes well within
#: a millisecond; the timeout bounds only how long a loaded 2-core machine may leave the
#: controller's process or thread unscheduled (the Python model at 50 ms retransmitted once in
#: a CI run, the QEMU image at 50 ms twice here), so it is generous and costs nothing.
CLEAN_LINK = RetryPolicy(timeout_s=1.0, retries=2, backoff_s=0.005)
