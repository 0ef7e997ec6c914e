"""``grassd studio --state-dir``: the daemon's archived bundles are the studio's lights (with
their lux) and its active table is shown against the simulated characteristic. A real daemon
(in-process, simulated controllers and lux sensor) calibrates one bundle first."""

from __future__ import annotations

import asyncio

from conftest import start_studio, stop_studio, ws_session
from daemon_harness import after_first_bundle


def test_the_daemons_bundles_and_active_table_reach_the_studio(tmp_path, hw):
    _sim, cfg = hw
    svc, table = after_first_bundle(tmp_path, cfg)
    config = svc.config_path
    svc.shutdown()
    studio = start_studio(tmp_path, "--config", str(config), "--state-dir",
                          str(tmp_path / "state"))
    try:
        status, state = studio.request("api/state")
        assert status == 200 and state["tables"]["active"] is True
        [bundle] = state["lights"]
        assert bundle["name"].startswith("bundle:") and bundle["label"].startswith("current: ")
        assert bundle["ambient_lux"] == 1000.0 and bundle["taken"].startswith("2026-03-01T11:00")
        inputs = {"type": "inputs", "id": 1, "condition": {
            "light": bundle["name"], "ambient_lux": 1000, "viewpoint": [170, 2, 0],
            "tables": "active", "target_stderr": 0.3}}
        got = asyncio.run(ws_session(studio.url, [inputs], until_id=1))
        assert got[-1]["type"] == "done", got[-1]
        shown = next(m for m in got if m["type"] == "table")
        assert shown["source"] == "active"
        assert [round(x * 1000) for x in shown["lengths_mm"]] == list(table.lengths_um)
        assert 0.9 < shown["r2_after"] <= 1.0
    finally:
        stop_studio(studio)
