"""``grassd sweep --scheduler``: a real dask scheduler and two dask workers on 127.0.0.1.

Checks that the cluster's results equal the local run's bit for bit, that a worker killed in
the middle of a sweep loses no task, and that a sweep resumes from partial output on the cluster.
Every process started here is killed in teardown (its own process group, by id).
"""

from __future__ import annotations

import os
import shutil
import signal
import socket
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from grassd.daemon.offline.sweep import SweepError, SweepSpec, conditions, read_results, run_sweep

pytest.importorskip("distributed")

SPEC = SweepSpec(lengths_mm=(0.0, 10.0, 20.0), samples=256, replicates=4, latitude=48.1,
                 longitude=11.6, date="2026-03-20", timezone="Europe/Berlin")
DASK = Path(sys.executable).parent / "dask"


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _wait_port(port: int, proc: subprocess.Popen, timeout_s: float) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise RuntimeError(f"dask scheduler exited with {proc.returncode}")
        try:
            with socket.create_connection(("127.0.0.1", port), timeout=0.5):
                return
        except OSError:
            time.sleep(0.2)
    raise TimeoutError(f"dask scheduler did not listen on {port} within {timeout_s} s")


def _stop(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        os.killpg(proc.pid, signal.SIGTERM)
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(10)


@pytest.fixture(scope="module")
def cluster(tmp_path_factory):
    """(address, {pid: Popen} of the two workers) of a fresh dask cluster on 127.0.0.1."""
    from distributed import Client

    if not DASK.exists():
        pytest.skip(f"{DASK} not installed")
    logs = tmp_path_factory.mktemp("dask")
    port = _free_port()
    addr = f"tcp://127.0.0.1:{port}"
    procs: list[subprocess.Popen] = []

    def start(args: list[str], name: str) -> subprocess.Popen:
        log = open(logs / f"{name}.log", "wb")  # closed with the process
        p = subprocess.Popen([str(DASK), *args], stdout=log, stderr=subprocess.STDOUT,
                             cwd=logs, start_new_session=True)
        procs.append(p)
        return p

    try:
        sched = start(["scheduler", "--host", "127.0.0.1", "--port", str(port),
                       "--no-dashboard"], "scheduler")
        _wait_port(port, sched, 30)
        workers = [start(["worker", addr, "--nthreads", "1", "--no-dashboard", "--no-nanny",
                          "--host", "127.0.0.1", "--death-timeout", "60", "--name", f"w{i}"],
                         f"worker{i}") for i in range(2)]
        with Client(addr, timeout=30, set_as_default=False) as client:
            client.wait_for_workers(2, timeout=60)
            pids = set(client.run(os.getpid).values())
        assert pids == {w.pid for w in workers}, "dask worker pids are not the started ones"
        yield addr, {w.pid: w for w in workers}
    finally:
        for p in reversed(procs):
            _stop(p)


@pytest.fixture(scope="module")
def sky(tmp_path_factory):
    from grassd.sim.hdri import write_exr

    env = np.ones((32, 64, 3), np.float32)
    env[:16] *= 2.5
    path = tmp_path_factory.mktemp("hdri") / "sky.exr"
    write_exr(path, env)
    return str(path)


def _conds(sky):
    return conditions([sky], ["07:00", "10:00", "13:00", "16:00"], [(170, 2, 0), (150, 3, 45)],
                      [("default", ()), ("splay8", (("splay_deg", 8.0),))])


@pytest.fixture(scope="module")
def local(sky, tmp_path_factory):
    out = tmp_path_factory.mktemp("local")
    run_sweep(SPEC, _conds(sky), out, workers=2, plots=False)
    return read_results(out / "sweep.sqlite", run_columns=False)


def test_cluster_equals_local_bit_for_bit(cluster, local, sky, tmp_path):
    addr, workers = cluster
    summary = run_sweep(SPEC, _conds(sky), tmp_path, scheduler=addr)
    assert summary.computed == 16 and summary.executor.startswith(f"dask {addr}")
    rows = read_results(tmp_path / "sweep.sqlite")
    used = {int(r["worker"].split(":")[1]) for r in rows}
    assert used == set(workers)  # both cluster workers traced, none of this process
    assert read_results(tmp_path / "sweep.sqlite", run_columns=False) == local
    assert (tmp_path / "summary.png").exists()


def test_worker_killed_mid_sweep_loses_no_task(cluster, local, sky, tmp_path):
    addr, workers = cluster
    seen: list[dict] = []
    victim: list[int] = []

    def on_result(row: dict) -> None:
        seen.append(row)
        if not victim:  # first result: kill the worker that produced it (it holds more work)
            pid = int(row["worker"].split(":")[1])
            assert pid in workers
            os.kill(pid, signal.SIGKILL)
            workers[pid].wait(10)
            victim.append(pid)

    summary = run_sweep(SPEC, _conds(sky), tmp_path, scheduler=addr, on_result=on_result,
                        plots=False)
    assert victim and summary.computed == 16 and len(seen) == 16
    # results kept arriving after the kill (it was mid-sweep), from the survivor only
    survivor = (set(workers) - set(victim)).pop()
    later = {int(r["worker"].split(":")[1]) for r in seen[4:]}  # in-flight ones aside
    assert later == {survivor}
    assert read_results(tmp_path / "sweep.sqlite", run_columns=False) == local


def test_resume_partial_output_on_the_cluster(cluster, local, sky, tmp_path):
    addr, _ = cluster
    conds = _conds(sky)
    # partial output: a local run of the first 6 conditions only
    run_sweep(SPEC, conds[:6], tmp_path, workers=1, plots=False)
    db = sqlite3.connect(tmp_path / "sweep.sqlite")
    assert db.execute("SELECT COUNT(DISTINCT key) FROM results").fetchone()[0] == 6
    db.close()
    summary = run_sweep(SPEC, conds, tmp_path, scheduler=addr, plots=False)
    assert (summary.skipped, summary.computed) == (6, 10)
    assert read_results(tmp_path / "sweep.sqlite", run_columns=False) == local


def test_unreachable_scheduler_is_a_clear_error(sky, tmp_path):
    port = _free_port()
    with pytest.raises(SweepError, match="cannot reach the Dask scheduler"):
        run_sweep(SPEC, _conds(sky)[:1], tmp_path, scheduler=f"tcp://127.0.0.1:{port}",
                  connect_timeout_s=2, plots=False)
    shutil.rmtree(tmp_path, ignore_errors=True)
