"""Firmware backends for tests: ``pytest.param`` lists that run a test against the Python model
and the C firmware (posix process, QEMU image), skipping a tier whose tools are missing."""

from __future__ import annotations

import shutil

import pytest

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


def firmware_params(*names: str) -> list:
    """``pytest.param(name)`` per firmware, marked skip (one line) when its tools are missing."""
    out = []
    for n in names:
        reason = missing_reason(n)
        marks = [pytest.mark.skip(reason=reason)] if reason else []
        out.append(pytest.param(n, id=n, marks=marks))
    return out
