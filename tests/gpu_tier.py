"""The GPU tier: tests of Taichi's ``gpu`` arch against its CPU arch. They need CUDA or a Vulkan
device; on a machine without a GPU, as in CI, Mesa's lavapipe (Debian's mesa-vulkan-drivers, a
Vulkan driver that runs on the CPU) is one: slow, but the same GPU backend (SPIR-V kernels,
arguments copied to the device) and the same code paths of grassd (launches that cannot be
stopped, :attr:`grassd.sim.renderer.Renderer.interruptible`)."""

from __future__ import annotations

import ctypes.util

import pytest

from grassd.sim.gpu_devices import vulkan_devices

#: The Vulkan devices of this machine (empty: none, or no loader).
DEVICES = vulkan_devices()

#: The tier's marks: the long tier (a software Vulkan compiles and traces slowly: about 1.5
#: minutes for the studio's tests on 2 cores), skipped with one line where there is no GPU arch.
GPU_TIER = [pytest.mark.long, pytest.mark.skipif(
    not DEVICES and not ctypes.util.find_library("cuda"),
    reason="GPU tier skipped: no Vulkan device or CUDA for Taichi's gpu arch "
           "(apt-get install mesa-vulkan-drivers: lavapipe, a Vulkan on the CPU; CI does)")]


def software_vulkan_only() -> bool:
    """Whether every Vulkan device here runs on the CPU (and there is one)."""
    return bool(DEVICES) and all(d.on_cpu for d in DEVICES)
