"""``grassd.sim.backend.init("gpu")`` on a machine without a GPU runs on the CPU and says so, in
each way a machine can lack one. Taichi 1.7.4 alone dies in all of them (a segmentation fault).

Each condition is made for real in the child process, whatever this machine has: the Vulkan
loader and the CUDA driver hidden by a mount namespace (or missing here), a loader shown no
driver file, a driver file whose library is no Vulkan driver, and a CUDA driver library that has
no device."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from no_gpu import hiding_prefix

from grassd.sim.gpu_devices import cuda_device_count, vulkan_loader_present

pytestmark = pytest.mark.skipif(cuda_device_count() > 0,
                                reason="this machine has a CUDA device: the gpu arch is CUDA here")

WARNING = "--arch gpu: Taichi found no GPU here (neither CUDA nor a Vulkan device)"
CHILD = ("import logging; logging.basicConfig()\n"
         "from grassd.sim import backend, gpu_devices\n"
         "print(gpu_devices.vulkan_loader_present(), gpu_devices.vulkan_devices(),"
         " gpu_devices.cuda_device_count())\n"
         "print(backend.init('gpu'))")
NEEDS_LOADER = pytest.mark.skipif(
    not vulkan_loader_present(),
    reason="no Vulkan loader here to show no driver (apt-get install libvulkan1)")


def _init_gpu(tmp_path: Path, argv_prefix: list[str] = (), **env: str) -> list[str]:
    """Run ``backend.init('gpu')`` in a child (``argv_prefix`` before its Python); return the
    lines it printed: what the probes saw, then the arch taken. Asserts it ran on the CPU with
    the one-line warning."""
    env = dict(os.environ, GRASSD_CACHE_DIR=str(tmp_path / "cache"), **env)
    done = subprocess.run([*argv_prefix, sys.executable, "-c", CHILD], capture_output=True,
                          text=True, env=env, timeout=120)
    assert done.returncode == 0, done.stderr[-2000:]
    lines = done.stdout.splitlines()
    assert lines[-1] in ("x64", "arm64"), done.stdout
    assert WARNING in done.stderr
    return lines


def test_no_vulkan_loader(tmp_path):
    """The bare machine: no ``libvulkan.so.1`` anywhere, nor ``libcuda.so.1``. Where this
    machine has either, the child runs in a mount namespace of its own with every file of them
    covered by /dev/null."""
    seen = _init_gpu(tmp_path, hiding_prefix())
    assert seen[0] == "False [] 0", seen


@NEEDS_LOADER
def test_a_loader_without_drivers(tmp_path):
    none = str(tmp_path / "no-driver.json")
    seen = _init_gpu(tmp_path, VK_ICD_FILENAMES=none, VK_DRIVER_FILES=none)
    assert seen[0] == "True [] 0", seen


@NEEDS_LOADER
def test_a_driver_file_whose_library_is_no_driver(tmp_path):
    """A driver file (ICD manifest) naming a library that offers no Vulkan device."""
    icd = tmp_path / "broken_icd.json"
    icd.write_text('{"file_format_version": "1.0.0", "ICD": {"library_path": "libm.so.6", '
                   '"api_version": "1.3.0"}}')
    seen = _init_gpu(tmp_path, VK_ICD_FILENAMES=str(icd), VK_DRIVER_FILES=str(icd))
    assert seen[0] == "True [] 0", seen


def test_a_cuda_driver_without_a_device(tmp_path):
    """NVIDIA's driver library installed where its device is not (a container without the
    device nodes, a GPU gone): ``cuInit`` answers CUDA_ERROR_NO_DEVICE (100). No Vulkan device
    either."""
    cc = shutil.which("cc")
    if cc is None:
        pytest.skip("no C compiler to build a CUDA driver without a device (apt-get install gcc)")
    source = tmp_path / "cuda.c"
    source.write_text("int cuInit(unsigned flags) { (void)flags; return 100; }\n"
                      "int cuDeviceGetCount(int *n) { *n = 0; return 100; }\n")
    subprocess.run([cc, "-shared", "-fPIC", "-o", str(tmp_path / "libcuda.so.1"), str(source)],
                   check=True)
    none = str(tmp_path / "no-driver.json")  # and no Vulkan device (lavapipe hidden)
    seen = _init_gpu(tmp_path, LD_LIBRARY_PATH=str(tmp_path), VK_ICD_FILENAMES=none,
                     VK_DRIVER_FILES=none)
    assert seen[0].endswith(" 0"), seen
