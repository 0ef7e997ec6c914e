"""Sweep benchmark: speed-up from 1 to 2 local workers, tasks/s, and a 2-worker Dask cluster.

Run: ``.venv/bin/python -m bench.bench_sweep`` (``--no-dask`` skips the cluster). Prints numbers,
asserts nothing. Each task: one pixel, 6 lengths (0:20:4), 4096 paths x 4 replicates per length.
Local wall times include starting the worker processes (spawn, Taichi init, kernel load); the
warm Dask runs (1 worker, then 2) show the compute speed-up alone.
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from grassd.daemon.compute.config import ComputeConfig
from grassd.daemon.offline.sweep import SweepSpec, conditions, read_results, run_sweep
from grassd.rigs.processes import end_process


def _sky(folder: Path) -> str:
    from grassd.sim.hdri import write_exr

    env = np.ones((64, 128, 3), np.float32)
    env[:32] *= 2.0
    path = folder / "sky.exr"
    write_exr(path, env)
    return str(path)


def _spec() -> SweepSpec:
    return SweepSpec(lengths_mm=(0.0, 4.0, 8.0, 12.0, 16.0, 20.0), samples=4096, replicates=4,
                     latitude=48.1, longitude=11.6, date="2026-06-21",
                     timezone="Europe/Berlin")


def _conds(sky: str):
    times = [f"{h:02d}:00" for h in range(6, 21, 2)]  # 8 times of day
    views = [(170, 2, 0), (160, 3, 45), (150, 1.5, -60)]
    return conditions([sky], times, views)  # 24 tasks


def _dask_cluster(workers: int) -> tuple[str, list[subprocess.Popen]]:
    dask = Path(sys.executable).parent / "dask"
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    addr = f"tcp://127.0.0.1:{port}"
    quiet = dict(stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    procs = [subprocess.Popen([str(dask), "scheduler", "--host", "127.0.0.1", "--port",
                               str(port), "--no-dashboard"], **quiet)]
    time.sleep(2)
    procs += [subprocess.Popen([str(dask), "worker", addr, "--nthreads", "1", "--no-dashboard",
                                "--no-nanny", "--host", "127.0.0.1"], **quiet)
              for _ in range(workers)]
    from distributed import Client

    with Client(addr, timeout=30, set_as_default=False) as c:
        c.wait_for_workers(workers, timeout=60)
    return addr, procs


def main() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        sky = _sky(tmp)
        spec, conds = _spec(), _conds(sky)
        print(f"{len(conds)} tasks, {len(spec.lengths_mm)} lengths x {spec.samples} paths x "
              f"{spec.replicates} replicates each; {os.cpu_count()} CPU cores")
        walls = {}
        for w in (1, 2):
            s = run_sweep(spec, conds, tmp / f"local{w}", workers=w, plots=False)
            walls[w] = s.seconds
            print(f"local, {w} worker(s): {s.seconds:7.2f} s  {s.tasks_per_s:6.2f} tasks/s  "
                  f"({s.executor})")
        print(f"speed-up 1 -> 2 local workers: {walls[1] / walls[2]:.2f}x")
        if "--no-dask" in sys.argv:
            return
        addr, procs = _dask_cluster(2)
        # loopback only: plain tcp:// is taken with allow_insecure (and a warning)
        compute = ComputeConfig(scheduler=addr, allow_insecure=True)
        try:
            s = run_sweep(spec, conds, tmp / "dask_cold", compute=compute, plots=False)
            print(f"dask, 2 workers (cold: first task per worker loads Taichi): "
                  f"{s.seconds:7.2f} s  {s.tasks_per_s:6.2f} tasks/s")
            s = run_sweep(spec, conds, tmp / "dask_warm", compute=compute, plots=False)
            print(f"dask, 2 workers (warm: kernels kept between sweeps):       "
                  f"{s.seconds:7.2f} s  {s.tasks_per_s:6.2f} tasks/s")
            two = s.seconds
            os.killpg(procs[-1].pid, signal.SIGTERM)  # down to one warm worker
            procs[-1].wait(30)
            s = run_sweep(spec, conds, tmp / "dask_one", compute=compute, plots=False)
            print(f"dask, 1 worker  (warm):                                     "
                  f"{s.seconds:7.2f} s  {s.tasks_per_s:6.2f} tasks/s")
            print(f"speed-up 1 -> 2 warm Dask workers: {s.seconds / two:.2f}x")
            same = (read_results(tmp / "dask_warm" / "sweep.sqlite", run_columns=False)
                    == read_results(tmp / "local2" / "sweep.sqlite", run_columns=False))
            print(f"dask results bit-identical to local: {same}")
        finally:
            for p in reversed(procs):
                end_process(p, 10.0, group=True)


if __name__ == "__main__":
    main()
