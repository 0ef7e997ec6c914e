"""The GPU tier: tests of Taichi's ``gpu`` arch against its CPU arch. They need CUDA or a Vulkan
device; on a machine without a GPU, as in CI, Mesa's lavapipe (Debian's mesa-vulkan-drivers, a
Vulkan driver that runs on the CPU) is one: slow, but the same GPU backend (SPIR-V kernels,
arguments copied to the device) and the same code paths of grassd (launches that cannot be
stopped, :attr:`grassd.sim.renderer.Renderer.interruptible`)."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from grassd.sim.gpu_devices import cuda_device_count

#: The Vulkan devices of this machine as (name, kind) (empty: none, or no loader). Asked in a
#: process of its own: a Vulkan instance loads its drivers (lavapipe brings Debian's LLVM 15)
#: into the process, and the test workers also load Taichi's and Dr.Jit's LLVM.
DEVICES: list[tuple[str, str]] = [tuple(d) for d in json.loads(subprocess.run(
    [sys.executable, "-c", "import json; from grassd.sim.gpu_devices import vulkan_devices; "
     "print(json.dumps([[d.name, d.kind] for d in vulkan_devices()]))"],
    capture_output=True, text=True, timeout=60).stdout or "[]")]

#: The tier's marks: the long tier (a software Vulkan compiles and traces slowly: about 1.5
#: minutes on 2 cores), skipped with one line where there is no GPU arch.
GPU_TIER = [pytest.mark.long, pytest.mark.skipif(
    not DEVICES and not cuda_device_count(),
    reason="GPU tier skipped: no Vulkan device or CUDA for Taichi's gpu arch "
           "(apt-get install mesa-vulkan-drivers: lavapipe, a Vulkan on the CPU; CI does)")]


def software_vulkan_only() -> bool:
    """Whether every Vulkan device here runs on the CPU (and there is one)."""
    return bool(DEVICES) and all(kind == "cpu" for _, kind in DEVICES)


def assert_ran_on_a_gpu_arch(taichi_log: str) -> None:
    """The process whose Taichi log (stderr) is ``taichi_log`` ran the gpu arch, not the CPU
    it falls back to (where the test would compare the CPU with itself)."""
    assert "Starting on arch=" in taichi_log, taichi_log[-2000:]
    arch = taichi_log.split("Starting on arch=", 1)[1].split()[0]
    assert arch not in ("x64", "arm64"), f"the gpu arch fell back to {arch}"
