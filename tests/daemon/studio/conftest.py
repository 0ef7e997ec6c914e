"""A real ``grassd studio`` process on 127.0.0.1 (port chosen by the OS) for the studio's tests:
started once per test module, its URL read from what it prints, stopped afterwards."""

from __future__ import annotations

import asyncio
import io
import json
import os
import subprocess
import sys
import time
import urllib.error
import urllib.request
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pytest

if TYPE_CHECKING:
    from grassd.daemon.studio.inputs import Condition
    from grassd.daemon.studio.session import Studio

from grassd.rigs.processes import end_process

#: A condition the studio computes quickly (5 lengths, no sun).
GOOD: dict = {"ambient_lux": 5000.0, "viewpoint": [170, 2, 0], "lengths_mm": [0, 5, 10, 15, 20]}
#: The studio's bench low sun (courtyard site, 15:00 in November, about 15 deg up).
LOW_SUN: dict = {"mode": "site", "lux": 40000, "when": "2026-11-27T15:00"}


def costly_condition(target_stderr: float, splay_deg: float) -> dict:
    """A condition that takes many seconds: 64 lengths of splayed blades under a low sun
    (given as a bundle manifest gives it) to ``target_stderr`` (dE00)."""
    return {**GOOD, "lengths_mm": [round(20 * i / 63, 3) for i in range(64)],
            "target_stderr": target_stderr, "splay_deg": splay_deg, "sun_lux": 30000,
            "sun_azimuth_deg": 180, "sun_elevation_deg": 15}


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


def start_studio(tmp: Path, *args: str, env: dict[str, str] | None = None,
                 argv_prefix: Sequence[str] = ()) -> StudioProcess:
    """Start ``grassd studio --port 0 ARGS`` (``env`` added to the environment; ``argv_prefix``
    before its Python, e.g. :func:`no_gpu.hiding_prefix`, which ends in an ``exec``) and wait
    until it serves and has warmed up."""
    log = tmp / "studio.log"
    env = dict(os.environ, PYTHONUNBUFFERED="1", **(env or {}))
    proc = subprocess.Popen([*argv_prefix, sys.executable, "-m", "grassd.daemon.cli", "studio",
                             "--port", "0", *args], stdout=subprocess.PIPE,
                            stderr=log.open("wb"), text=True, env=env)
    line = proc.stdout.readline()
    if not line.startswith("grassd studio: http"):
        proc.kill()
        raise AssertionError(f"studio did not start: {line!r} {log.read_text()}")
    url = line.split(": ", 1)[1].strip()
    token = url.split("token=")[1] if "token=" in url else None
    studio = StudioProcess(url.split("?")[0], proc, log, token)
    deadline = time.monotonic() + 240
    while True:  # the first start compiles the kernels (later ones load them from the cache)
        status, state = studio.request("api/state",
                                       headers={"X-Grassd-Token": token} if token else None)
        if status == 200 and state["ready"]:
            return studio
        assert proc.poll() is None, log.read_text()
        assert time.monotonic() < deadline, "studio did not warm up in 240 s"
        time.sleep(0.3)


def png_bytes(levels: np.ndarray, mode: str = "L") -> bytes:
    """``levels`` (uint8 values: rows x cols, or rows x cols x 3 with ``mode`` "RGB") as a PNG."""
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(levels.astype(np.uint8), mode).save(buf, "PNG")
    return buf.getvalue()


async def ws_session(url: str, requests: list[dict], until_id: int,
                     timeout_s: float = 120) -> list[dict]:
    """Send the inputs over one WebSocket; every message received until ``until_id`` is done
    (or has an error), within ``timeout_s``."""
    import aiohttp

    got = []
    async with aiohttp.ClientSession() as s, s.ws_connect(url.replace("http", "ws") + "ws") as ws:
        for r in requests:
            await ws.send_str(json.dumps(r))
        async with asyncio.timeout(timeout_s):
            async for m in ws:
                msg = json.loads(m.data)
                got.append(msg)
                if msg["id"] == until_id and msg["type"] in ("done", "error"):
                    return got
    return got


def stop_studio(studio: StudioProcess) -> None:
    """End the process (SIGTERM, then SIGKILL)."""
    end_process(studio.proc, 15)


@pytest.fixture(scope="module")
def studio(tmp_path_factory, shared_hdri) -> Iterator[StudioProcess]:
    """The studio lit by ../shared/hdri/courtyard.exr (skips when shared/ is absent)."""
    hdri = shared_hdri("courtyard")
    s = start_studio(tmp_path_factory.mktemp("studio"), "--hdri", str(hdri))
    yield s
    stop_studio(s)


def studio_and_condition(hdri: Path, condition: dict) -> tuple[Studio, Condition]:
    """An in-process studio of the default config lit by ``hdri`` (light "f"), and
    ``condition`` (the page's JSON) parsed for it."""
    from grassd.daemon.core.config.settings import resolve_config
    from grassd.daemon.studio.lights import Lights, LightSource
    from grassd.daemon.studio.session import Studio

    st = Studio(resolve_config(None, None), Lights([LightSource("file", "f", hdri)]))
    return st, st.parse(condition)


def vm_mib(pid: int, field: str = "VmHWM") -> float:
    """A process's ``field`` of /proc/<pid>/status (VmHWM: its peak resident set; VmRSS: its
    resident set now) in MiB."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith(field + ":"):
            return int(line.split()[1]) / 1024
    raise AssertionError(f"no {field} for process {pid}")


def simulator_pid(studio: StudioProcess) -> int:
    """The pid of the studio's simulator process (as ``/api/state`` gives it)."""
    headers = {"X-Grassd-Token": studio.token} if studio.token else None
    status, state = studio.request("api/state", headers=headers)
    assert status == 200, state
    return state["simulator"]["pid"]
