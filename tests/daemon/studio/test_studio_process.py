"""The studio's simulator process (``grassd.daemon.studio.process``): a newer job of the same
owner, or the studio's end, stops the renderer's launch in flight through the word the two
processes share, instead of waiting for it to end."""

from __future__ import annotations

import asyncio
import time
from collections.abc import AsyncIterator, Callable
from contextlib import asynccontextmanager
from pathlib import Path

import pytest

from grassd.daemon.studio.worker import Superseded
from grassd.sim.scene import MAX_SAMPLES

# Paths a replicate of the probe that times the machine (2 replicates).
PROBE_PATHS = 1 << 16
# Seconds the long job's launches are sized to by the probe's rate (which overstates them: on 2
# cores they took about 11 s).
LONG_LAUNCH_S = 20.0


@asynccontextmanager
async def simulator(hdri: Path) -> AsyncIterator[tuple[object, Callable[..., object], float]]:
    """A started simulator process lit by the panorama ``hdri``, the job payload of
    ``samples`` splayed camera paths a replicate at 2 lengths, and the seconds a path takes
    here, as a probe of 2 x :data:`PROBE_PATHS` paths timed it."""
    from grassd.daemon.core.config.settings import resolve_config
    from grassd.daemon.studio.inputs import parse_condition
    from grassd.daemon.studio.lights import LightSource
    from grassd.daemon.studio.process import CurveJob, SimulatorProcess, StudioArgs

    cfg = resolve_config(None, None)
    cond = parse_condition({"ambient_lux": 5000, "viewpoint": [170, 2, 0], "splay_deg": 8.0,
                            "lengths_mm": [0, 20]},
                           green_max_mm=20.0, timezone=cfg.site.timezone, lights=["file"],
                           default_light="file")

    def job(samples: int, replicates: int = 2) -> CurveJob:
        return CurveJob(cond, {"target_stderr": None, "samples": samples,
                               "replicates": replicates, "lengths_mm": [0.0, 20.0]})

    ready = asyncio.Event()
    sim = SimulatorProcess(StudioArgs(None, None, (LightSource("file", "courtyard", hdri),)),
                           lambda _s: ready.set())
    try:
        await asyncio.wait_for(ready.wait(), 300)  # the first start compiles the kernels
        probe = await asyncio.wait_for(sim.submit(1, job(PROBE_PATHS)), 120)
        per_path = probe.seconds["trace"] / (2 * PROBE_PATHS)
        yield sim, job, per_path
    finally:
        sim.stop()


def long_paths(per_path: float) -> int:
    """Paths a replicate of the long job: :data:`LONG_LAUNCH_S` by the probe, at most
    ``MAX_SAMPLES``; a machine that traces those in under 3 s has no launch long enough to stop."""
    paths = min(MAX_SAMPLES, int(LONG_LAUNCH_S / per_path))
    if paths * per_path < 3.0:
        pytest.skip(f"this machine traces {paths} paths in {paths * per_path:.1f} s: "
                    f"no launch here is long enough to stop in flight")
    return paths


def test_a_newer_job_stops_the_launch_in_flight(shared_hdri):
    """Job A's replicates of splayed camera paths are sized to long launches by a probe's rate
    (at most a replicate's 4 million paths); job B, sent 1 s after A started, supersedes A and
    is answered within a third of A's launch: A's launch stopped within the camera path in
    flight. Without the shared word B waits for A's launch to end, two thirds of it later
    (docs/studio.md has the times measured)."""

    async def scenario() -> tuple[float, object, BaseException | None, float]:
        async with simulator(shared_hdri("courtyard")) as (sim, job, per_path):
            paths = long_paths(per_path)
            slow = sim.submit(1, job(paths, 4))
            await asyncio.sleep(1.0)  # A is running: the worker was idle
            t0 = time.monotonic()
            curve = await asyncio.wait_for(sim.submit(1, job(256)), 120)
            answered = time.monotonic() - t0
            try:
                await asyncio.wait_for(slow, 5)
                error = None
            except BaseException as exc:  # noqa: BLE001 (what A ended with is the finding)
                error = exc
            return answered, curve, error, paths * per_path

    answered, curve, error, launch_s = asyncio.run(scenario())
    assert isinstance(error, Superseded), error
    assert curve.ogcd.shape == (2,)
    assert answered < launch_s / 3, (
        f"B answered {answered:.1f} s after it was sent; A's launch takes about "
        f"{launch_s:.1f} s")


def test_the_studio_ends_within_a_camera_path_of_a_long_launch(shared_hdri):
    """Stopping the simulator 1 s into a long launch ends its process cleanly (exit code 0,
    the job superseded) within a third of the launch and 5 s (measured on 2 cores: 0.5-0.7 s,
    most of it the process's exit); without moving the word it waited for the launch to end
    (7.5 s)."""

    async def scenario() -> tuple[float, float, object, BaseException | None]:
        async with simulator(shared_hdri("courtyard")) as (sim, job, per_path):
            paths = long_paths(per_path)
            slow = sim.submit(1, job(paths, 4))
            await asyncio.sleep(1.0)
            t0 = time.monotonic()
            sim.stop()
            took = time.monotonic() - t0
            await asyncio.wait([slow], timeout=5)  # the simulator's last message reaches it
            return (took, paths * per_path, sim.proc.exitcode,
                    slow.exception() if slow.done() else None)

    took, launch_s, exitcode, error = asyncio.run(scenario())
    assert exitcode == 0
    assert isinstance(error, Superseded), error
    assert took < min(5.0, launch_s / 3), (
        f"the simulator ended {took:.1f} s after it was told to; its launch takes about "
        f"{launch_s:.1f} s")
