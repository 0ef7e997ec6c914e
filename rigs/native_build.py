"""Building the C firmware in ``firmware/`` (next to this package in a source checkout).

:func:`build_firmware` runs ``make -C firmware <target>`` once per process and target, under a
file lock (parallel test processes share one build). Typed errors say what is missing.
"""

from __future__ import annotations

import fcntl
import shutil
import subprocess
import threading
from pathlib import Path

from grassd.firmware_proto.errors import SimulatorError

#: The firmware sources: ``firmware/`` at the top of the source tree.
FIRMWARE_DIR = Path(__file__).resolve().parents[1] / "firmware"
#: Where ``make`` puts what it builds (ignored by git).
BUILD_DIR = FIRMWARE_DIR / "build"

_built: dict[str, Path] = {}
_lock = threading.Lock()


class FirmwareUnavailable(SimulatorError):
    """The C firmware cannot be built here (no source tree, no C compiler or make, no ARM
    toolchain); the message says what to install."""


def build_firmware(target: str, output: str) -> Path:
    """Run ``make -C firmware target`` (incremental) and return ``firmware/build/<output>``.

    Raises :class:`FirmwareUnavailable` when the sources, ``make`` or the compiler are missing,
    with the compiler's output when the build fails.
    """
    with _lock:
        if target in _built:
            return _built[target]
        if not (FIRMWARE_DIR / "Makefile").exists():
            raise FirmwareUnavailable(f"the C firmware sources are not at {FIRMWARE_DIR}: the "
                                      f"posix and qemu firmware need a source checkout of grassd")
        if shutil.which("make") is None:
            raise FirmwareUnavailable("`make` is not installed; apt-get install make gcc")
        BUILD_DIR.mkdir(exist_ok=True)
        with open(BUILD_DIR / ".lock", "w") as lock:
            fcntl.flock(lock, fcntl.LOCK_EX)
            proc = subprocess.run(["make", "-s", "-C", str(FIRMWARE_DIR), target],
                                  capture_output=True, text=True)
        if proc.returncode != 0:
            raise FirmwareUnavailable(f"building the firmware ({target}) failed:\n"
                                      f"{proc.stdout}{proc.stderr}".strip())
        _built[target] = BUILD_DIR / output
        return _built[target]


def posix_firmware() -> Path:
    """Path of the built posix firmware process (``grassfw-posix``), building it if needed."""
    return build_firmware("posix", "grassfw-posix")


def mps2_image() -> Path:
    """Path of the Cortex-M7 image for ``qemu-system-arm -M mps2-an500``, building it if
    needed; :class:`FirmwareUnavailable` when arm-none-eabi-gcc is missing."""
    if shutil.which("arm-none-eabi-gcc") is None:
        raise FirmwareUnavailable("arm-none-eabi-gcc is not on PATH: apt-get install "
                                  "gcc-arm-none-eabi libnewlib-arm-none-eabi")
    return build_firmware("arm", "mps2/grassfw-mps2.elf")
