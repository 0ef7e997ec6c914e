"""The studio's tests: a real ``grassd studio`` process on 127.0.0.1
(:mod:`grassd.rigs.studio_process`) started once per test module, the conditions they ask and
a WebSocket page's session."""

from __future__ import annotations

import asyncio
import io
import json
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pytest

from grassd.rigs.studio_process import StudioProcess, start_studio, stop_studio

if TYPE_CHECKING:
    from grassd.daemon.studio.inputs import Condition
    from grassd.daemon.studio.session import Studio

__all__ = ["StudioProcess", "start_studio", "stop_studio"]

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
