"""``grassd.sim.backend.init("gpu")`` on a machine without a GPU: it runs on the CPU and says so,
where Taichi 1.7.4 alone dies when the Vulkan loader lists no device (a segmentation fault)."""

import os
import subprocess
import sys

import pytest

from grassd.sim.gpu_devices import cuda_driver_present


def test_the_gpu_arch_without_a_gpu_runs_on_the_cpu_and_says_so(tmp_path):
    if cuda_driver_present():
        pytest.skip("this machine has NVIDIA's driver: Taichi's gpu arch is CUDA here")
    # A loader with no driver file lists no device (lavapipe hidden too); without a loader
    # (a bare Debian) Taichi falls back to the CPU itself: the same outcome.
    none = str(tmp_path / "no-driver.json")
    env = dict(os.environ, VK_ICD_FILENAMES=none, VK_DRIVER_FILES=none,
               GRASSD_CACHE_DIR=str(tmp_path / "cache"))
    code = ("import logging; logging.basicConfig()\n"
            "from grassd.sim import backend\nprint(backend.init('gpu'))")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env,
                          timeout=120)
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.split() == ["x64"] or done.stdout.split() == ["arm64"]
    assert "--arch gpu: Taichi found no GPU here (neither CUDA nor a Vulkan device)" in done.stderr
