"""``grassd studio --arch gpu`` on a machine with no GPU stack at all (no Vulkan loader, no CUDA
driver; where this machine has either, it is hidden from the studio by a mount namespace):
the studio serves, its simulator runs on the CPU and says so in one line, and a characteristic
request is answered."""

from __future__ import annotations

import math

from conftest import GOOD, start_studio, stop_studio
from no_gpu import hiding_prefix

WARNING = "--arch gpu: Taichi found no GPU here (neither CUDA nor a Vulkan device)"


def test_the_gpu_arch_without_a_gpu_answers_on_the_cpu(tmp_path):
    studio = start_studio(tmp_path, "--arch", "gpu", argv_prefix=hiding_prefix())
    try:
        status, body = studio.request("api/characteristic", GOOD)
        assert studio.proc.poll() is None, studio.log.read_text()[-2000:]
    finally:
        stop_studio(studio)
    log = studio.log.read_text()
    assert status == 200, (body, log[-2000:])
    assert body["lengths_mm"] == GOOD["lengths_mm"], body
    assert len(body["ogcd"]) == len(body["ogcd_stderr"]) == len(GOOD["lengths_mm"]), body
    assert all(math.isfinite(v) for v in body["ogcd"]) and body["ogcd"][-1] > 0, body
    assert len([ln for ln in log.splitlines() if WARNING in ln]) == 1, log[-2000:]
    assert "Starting on arch=" in log, log[-2000:]
    assert log.split("Starting on arch=", 1)[1].split()[0] in ("x64", "arm64"), log[-2000:]
