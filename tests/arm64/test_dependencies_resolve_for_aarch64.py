"""grassd's dependencies resolve for Linux aarch64 from wheels alone, without Taichi (which has
no aarch64 wheels, taichi-dev/taichi#8756), while x86-64 Linux still gets Taichi. ``uv pip
compile --python-platform`` evaluates the markers for the target platform; pip's
``--platform`` would evaluate them for this machine."""

from __future__ import annotations

import re
import subprocess

import pytest
from arm64_root import REPO, uv

#: dependencies an ARM box at the display needs, each with aarch64 wheels
NEEDED = {"numpy", "scipy", "rawpy", "openexr", "colour-science", "colour-hdri", "pymodbus",
          "pyserial", "click", "distributed", "prometheus-client"}


def _resolve(platform: str) -> set[str]:
    """The names ``uv pip compile pyproject.toml`` pins for ``platform``, wheels only."""
    try:
        exe = uv()
    except FileNotFoundError:
        pytest.skip("aarch64 resolution check skipped: uv not installed (pip install uv; "
                    "the test extra has it)")
    p = subprocess.run([exe, "pip", "compile", "pyproject.toml", "--python-platform", platform,
                        "--only-binary", ":all:", "--no-header", "--no-annotate", "-q"],
                       cwd=REPO, capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, f"dependencies do not resolve for {platform}:\n{p.stderr}"
    return {m.group(1).lower() for m in re.finditer(r"(?m)^([A-Za-z0-9_.-]+)==", p.stdout)}


def test_dependencies_resolve_for_aarch64_from_wheels_without_taichi():
    pins = _resolve("aarch64-manylinux_2_28")
    assert "taichi" not in pins
    assert NEEDED <= pins, f"missing for aarch64: {sorted(NEEDED - pins)}"


def test_x86_64_linux_still_gets_taichi():
    pins = _resolve("x86_64-manylinux_2_28")
    assert {"taichi"} | NEEDED <= pins
