"""``grassd studio --arch gpu``, against the same studio on the CPU: Taichi's GPU backend (CUDA or
Vulkan, whichever Taichi finds; on a machine without a GPU, as in CI, Mesa's lavapipe, a Vulkan
driver that runs on the CPU) gives the same numbers for the same request (the same seeds), and a
page's inputs get every view, superseded as on the CPU, through the launches a GPU keeps (a
kernel there cannot read the interrupt word, so the newer input is read between small
launches)."""

from __future__ import annotations

import asyncio

import numpy as np
import pytest
from conftest import GOOD, png_bytes, start_studio, stop_studio, ws_session
from gpu_tier import GPU_TIER, assert_ran_on_a_gpu_arch, software_vulkan_only

pytestmark = GPU_TIER


@pytest.fixture(scope="module")
def gpu_studio(tmp_path_factory, shared_hdri):
    """The studio of the ``studio`` fixture (courtyard.exr) with ``--arch gpu``."""
    s = start_studio(tmp_path_factory.mktemp("gpu-studio"), "--hdri",
                     str(shared_hdri("courtyard")), "--arch", "gpu")
    assert_ran_on_a_gpu_arch(s.log.read_text())  # its simulator has warmed up
    yield s
    stop_studio(s)


def test_the_same_request_gives_the_cpus_numbers(gpu_studio, studio):
    """Without a target both trace the same replicates with the same seeds: the OGCD agrees to
    float rounding (a ray grazing a blade's edge may take the other branch on one of them).

    A replicate moved by d moves the mean of n by d/n and the standard error (ddof 1) by at most
    d/n too, so the standard errors may differ by the means' difference beyond rounding; a
    standard error computed another way (n for n - 1: 7 % at 8 replicates) exceeds that."""
    ask = {**GOOD, "sun_lux": 30000, "sun_azimuth_deg": 200, "sun_elevation_deg": 20,
           "splay_deg": 8}
    status, gpu = gpu_studio.request("api/characteristic", ask)
    assert status == 200, gpu
    status, cpu = studio.request("api/characteristic", ask)
    assert status == 200, cpu
    assert gpu["replicates"] == cpu["replicates"]
    se = np.hypot(gpu["ogcd_stderr"], cpu["ogcd_stderr"])
    diff = np.abs(np.subtract(gpu["ogcd"], cpu["ogcd"]))
    assert cpu["ogcd"][-1] > 10 and np.all(diff <= 0.2 * se + 1e-3), (gpu, cpu)
    moved = np.abs(np.subtract(gpu["ogcd_stderr"], cpu["ogcd_stderr"]))
    assert np.all(moved <= diff + 0.02 * np.asarray(cpu["ogcd_stderr"]) + 1e-4), (gpu, cpu)


def test_a_pages_inputs_get_every_view_and_the_newer_supersedes(gpu_studio):
    status, pic = gpu_studio.request("api/picture",
                                     png_bytes(np.tile(np.linspace(0, 255, 16), (8, 1))))
    assert status == 200, pic
    old = {"type": "inputs", "id": 1, "condition": {"ambient_lux": 5000, "viewpoint": [170, 2, 0]}}
    new = {"type": "inputs", "id": 2, "condition": {
        "ambient_lux": 8000, "viewpoint": [160, 3, 25], "image": pic["image"],
        "lengths_mm": GOOD["lengths_mm"], "target_stderr": 0.3}}
    got = asyncio.run(ws_session(gpu_studio.url, [old, new], until_id=2, timeout_s=300))
    assert not any(m["type"] == "done" for m in got if m["id"] == 1)  # superseded
    mine = [m for m in got if m["id"] == 2]
    kinds = [m["type"] for m in mine]
    assert {"light", "curve", "pixel", "table", "contrast", "display", "audience"} <= set(kinds)
    assert kinds[-1] == "done", [m for m in mine if m["type"] == "error"]
    curves = [m for m in mine if m["type"] == "curve"]
    assert curves[-1]["converged"] and curves[-1]["max_stderr"] <= 0.3
    pixels = [m for m in mine if m["type"] == "pixel"]
    assert pixels[-1]["spp"] > pixels[0]["spp"]


def test_a_software_vulkan_is_named_at_start(gpu_studio):
    """On a Vulkan that runs on the CPU the user learns why --arch gpu is slow."""
    if not software_vulkan_only():
        pytest.skip("this machine has a GPU: nothing to warn about")
    assert "a Vulkan driver that runs on the CPU" in gpu_studio.log.read_text()
