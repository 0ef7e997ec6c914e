"""A real ``grassd studio`` process on 127.0.0.1 (port chosen by the OS), for the studio's
tests and benchmarks: started, its URL and token read from what it prints, waited for until
it has warmed up, and stopped.

Used by ``tests/daemon/studio/`` and ``bench_hostile``.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
import urllib.error
import urllib.request
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from grassd.rigs.processes import end_process


class StudioNotStarted(RuntimeError):
    """The studio process did not print its URL or did not warm up (the message holds its log)."""


@dataclass
class StudioProcess:
    """A running studio: its base ``url`` (ending in /), the process, its stderr file and the
    token it printed (None on 127.0.0.1)."""

    url: str
    proc: subprocess.Popen
    log: Path
    token: str | None = None

    def request(self, path: str, body: bytes | dict | None = None,
                headers: dict[str, str] | None = None) -> tuple[int, dict]:
        """(HTTP status, JSON body) of GET (no body) or POST ``path``."""
        data = json.dumps(body).encode() if isinstance(body, dict) else body
        req = urllib.request.Request(self.url + path.lstrip("/"), data=data,
                                     headers=headers or {},
                                     method="GET" if body is None else "POST")
        try:
            with urllib.request.urlopen(req, timeout=120) as r:
                return r.status, json.loads(r.read())
        except urllib.error.HTTPError as exc:
            return exc.code, json.loads(exc.read())

    def simulator_pid(self) -> int:
        """The pid of the studio's simulator process (as ``/api/state`` gives it)."""
        headers = {"X-Grassd-Token": self.token} if self.token else None
        status, state = self.request("api/state", headers=headers)
        if status != 200:
            raise StudioNotStarted(f"api/state answered {status}: {state}")
        return int(state["simulator"]["pid"])


def start_studio(tmp: Path, *args: str, env: dict[str, str] | None = None,
                 argv_prefix: Sequence[str] = (), warm_s: float = 240.0) -> StudioProcess:
    """Start ``grassd studio --port 0 ARGS`` (``env`` added to the environment; ``argv_prefix``
    before its Python, e.g. ``tests/no_gpu.py``'s hiding prefix, which ends in an ``exec``),
    its log in ``tmp``/studio.log, and wait until it serves and has warmed up (at most
    ``warm_s`` seconds: the first start compiles the kernels, later ones load them)."""
    log = tmp / "studio.log"
    env = dict(os.environ, PYTHONUNBUFFERED="1", **(env or {}))
    proc = subprocess.Popen([*argv_prefix, sys.executable, "-m", "grassd.daemon.cli", "studio",
                             "--port", "0", *args], stdout=subprocess.PIPE,
                            stderr=log.open("wb"), text=True, env=env)
    line = proc.stdout.readline()
    if not line.startswith("grassd studio: http"):
        proc.kill()
        raise StudioNotStarted(f"studio did not start: {line!r} {log.read_text()}")
    url = line.split(": ", 1)[1].strip()
    token = url.split("token=")[1] if "token=" in url else None
    studio = StudioProcess(url.split("?")[0], proc, log, token)
    deadline = time.monotonic() + warm_s
    while True:
        status, state = studio.request("api/state",
                                       headers={"X-Grassd-Token": token} if token else None)
        if status == 200 and state["ready"]:
            return studio
        if proc.poll() is not None or time.monotonic() > deadline:
            end_process(proc, 15)
            raise StudioNotStarted(f"studio did not warm up in {warm_s:g} s: "
                                   f"{log.read_text()[-2000:]}")
        time.sleep(0.3)


def stop_studio(studio: StudioProcess) -> None:
    """End the process (SIGTERM, then SIGKILL)."""
    end_process(studio.proc, 15)
