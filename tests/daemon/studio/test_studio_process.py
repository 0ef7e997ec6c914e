"""The studio's simulator process (``grassd.daemon.studio.process``): a newer job of the same
owner stops the renderer's launch in flight, through the word the two processes share, instead
of waiting for it to end."""

from __future__ import annotations

import asyncio
import time

import pytest
from conftest import HDRI_DIR

from grassd.daemon.studio.worker import Superseded

# Paths a replicate of the probe that times the machine (2 replicates), and the most a
# replicate takes (the renderer's buffer, Capacity.paths).
PROBE_PATHS = 1 << 16
MOST_PATHS = 1 << 22


def test_a_newer_job_stops_the_launch_in_flight():
    """A probe times the machine; job A's replicates of splayed camera paths at 2 lengths are
    sized from it to launches of about 12 s by the probe's rate (at most the buffer's 4
    million paths); job B, sent 1 s after A started, supersedes A and is answered within a
    third of that and 5 s (measured on 2 cores: 0.02 s): A's launch stopped within the camera
    path in flight. Without the shared word B waited for A's launch
    to end (6.7 s after it was sent)."""
    from grassd.daemon.config.settings import resolve_config
    from grassd.daemon.studio.inputs import parse_condition
    from grassd.daemon.studio.lights import LightSource
    from grassd.daemon.studio.process import SimulatorProcess, StudioArgs

    hdri = HDRI_DIR / "courtyard.exr"
    if not hdri.exists():
        pytest.skip(f"{hdri} not present (CI provides ../shared beside the clone)")
    cfg = resolve_config(None, None)
    cond = parse_condition({"ambient_lux": 5000, "viewpoint": [170, 2, 0], "splay_deg": 8.0,
                            "lengths_mm": [0, 20]},
                           green_max_mm=20.0, timezone=cfg.site.timezone, lights=["file"],
                           default_light="file")

    async def scenario() -> tuple[float, object, BaseException | None, float]:
        ready = asyncio.Event()
        sim = SimulatorProcess(StudioArgs(None, None, (LightSource("file", "courtyard", hdri),)),
                               lambda _s: ready.set())
        try:
            await asyncio.wait_for(ready.wait(), 300)  # the first start compiles the kernels
            probe = await asyncio.wait_for(sim.submit(1, "characteristic", (cond, {
                "target_stderr": None, "samples": PROBE_PATHS, "replicates": 2,
                "lengths_mm": [0.0, 20.0]})), 120)
            per_path = probe.seconds["trace"] / (2 * PROBE_PATHS)
            paths = min(MOST_PATHS, int(12.0 / per_path))
            slow = sim.submit(1, "characteristic", (cond, {
                "target_stderr": None, "samples": paths, "replicates": 4,
                "lengths_mm": [0.0, 20.0]}))
            await asyncio.sleep(1.0)  # A is running: the worker was idle
            t0 = time.monotonic()
            quick = sim.submit(1, "characteristic", (cond, {
                "target_stderr": None, "samples": 256, "replicates": 2,
                "lengths_mm": [0.0, 20.0]}))
            curve = await asyncio.wait_for(quick, 120)
            answered = time.monotonic() - t0
            try:
                await asyncio.wait_for(slow, 5)
                error = None
            except BaseException as exc:  # noqa: BLE001 (what A ended with is the finding)
                error = exc
            return answered, curve, error, paths * per_path
        finally:
            sim.stop()

    answered, curve, error, launch_s = asyncio.run(scenario())
    assert isinstance(error, Superseded), error
    assert curve.ogcd.shape == (2,)
    assert answered < min(5.0, launch_s / 3), (
        f"B answered {answered:.1f} s after it was sent; A's launch takes about "
        f"{launch_s:.1f} s")
