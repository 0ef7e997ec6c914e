"""A real dask.distributed cluster on 127.0.0.1 for tests: a ``dask scheduler`` process and
``dask worker`` processes (no nanny, so a killed worker stays dead), each in its own process
group, their output in log files. Workers get ``$GRASSD_CACHE_DIR`` (the tests' shared Taichi
kernel cache) and one thread (Taichi uses every core itself).

    with DaskCluster(tmp_path) as cluster:      # starts the scheduler
        cluster.add_worker("w1")                # and a worker; cluster.address: tcp://127.0.0.1:N
        ...                                     # [compute] scheduler = cluster.address
        cluster.kill_worker("w1")               # SIGKILL, as a crash
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

DASK = Path(sys.executable).parent / "dask"


def free_port() -> int:
    """A TCP port free on 127.0.0.1 right now."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class DaskCluster:
    """A scheduler on a free port of 127.0.0.1 and the workers added to it (see the module
    docstring); skips the test where the ``dask`` command is not installed."""

    def __init__(self, logs: Path, cache_dir: str | None = None) -> None:
        if not DASK.exists():
            pytest.skip(f"{DASK} not installed (pip install 'dask[distributed]')")
        self.logs = logs
        self.logs.mkdir(parents=True, exist_ok=True)
        self.port = free_port()
        self.address = f"tcp://127.0.0.1:{self.port}"
        self.env = dict(os.environ)
        if cache_dir is not None:
            self.env["GRASSD_CACHE_DIR"] = cache_dir
        self.scheduler: subprocess.Popen | None = None
        self.workers: dict[str, subprocess.Popen] = {}

    def _start(self, args: list[str], name: str) -> subprocess.Popen:
        with open(self.logs / f"{name}.log", "ab") as log:
            return subprocess.Popen([str(DASK), *args], stdout=log, stderr=subprocess.STDOUT,
                                    cwd=self.logs, env=self.env, start_new_session=True)

    def __enter__(self) -> DaskCluster:
        self.scheduler = self._start(["scheduler", "--host", "127.0.0.1", "--port",
                                      str(self.port), "--no-dashboard"], "scheduler")
        deadline = time.monotonic() + 30
        while True:
            if self.scheduler.poll() is not None:
                raise RuntimeError(f"dask scheduler exited with {self.scheduler.returncode}")
            try:
                with socket.create_connection(("127.0.0.1", self.port), timeout=0.5):
                    return self
            except OSError:
                if time.monotonic() > deadline:
                    raise TimeoutError(f"dask scheduler not listening on {self.port}") from None
                time.sleep(0.2)

    def add_worker(self, name: str, timeout_s: float = 60.0) -> int:
        """Start worker ``name`` and wait until the scheduler lists it; returns its pid."""
        from distributed import Client

        p = self._start(["worker", self.address, "--nthreads", "1", "--no-dashboard",
                         "--no-nanny", "--host", "127.0.0.1", "--death-timeout", "60",
                         "--name", name], f"worker-{name}")
        self.workers[name] = p
        with Client(self.address, timeout=30, set_as_default=False) as client:
            deadline = time.monotonic() + timeout_s
            while p.pid not in set(client.run(os.getpid).values()):
                assert p.poll() is None, f"dask worker {name} exited with {p.returncode}"
                assert time.monotonic() < deadline, f"dask worker {name} did not join"
                time.sleep(0.2)
        return p.pid

    def kill_worker(self, name: str) -> None:
        """SIGKILL worker ``name`` (a crash: no goodbye to the scheduler) and reap it."""
        p = self.workers.pop(name)
        os.killpg(p.pid, signal.SIGKILL)
        p.wait(10)

    def __exit__(self, *exc: object) -> None:
        for p in [*self.workers.values(), self.scheduler]:
            if p is None or p.poll() is not None:
                continue
            os.killpg(p.pid, signal.SIGTERM)
            try:
                p.wait(10)
            except subprocess.TimeoutExpired:
                os.killpg(p.pid, signal.SIGKILL)
                p.wait(10)
        self.workers.clear()
