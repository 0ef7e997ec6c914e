"""The studio's HTTP JSON API and WebSocket, against a real ``grassd studio`` process: the
characteristic it returns is the daemon's simulation, bad input gets a 4xx naming the value and
the server goes on serving, uploads become lights and pictures, and a page's newer inputs
supersede its older ones while the views stream in order."""

from __future__ import annotations

import asyncio

import numpy as np
import pytest
from conftest import GOOD, costly_condition, png_bytes, start_studio, stop_studio, ws_session


def test_characteristic_refines_to_the_target(studio):
    status, body = studio.request("api/characteristic", {**GOOD, "target_stderr": 0.1})
    assert status == 200, body
    assert body["lengths_mm"] == GOOD["lengths_mm"]
    ogcd, se = np.array(body["ogcd"]), np.array(body["ogcd_stderr"])
    assert ogcd[0] == 0.0 and se[0] == 0.0  # the reference
    assert np.all(se[1:] > 0) and se.max() <= 0.1
    assert ogcd[-1] > 10 and np.all(np.diff(ogcd) > -3 * se[1:].max())
    assert body["replicates"] >= 4 and body["seconds"] > 0


def test_characteristic_without_target_is_the_daemons_simulation(studio, renderer, shared_hdri):
    """Same config, light, seed and settings ([simulation] samples x [calibration]
    replicates): the same numbers as simulate_curve in this process."""
    from grassd.daemon.core.calibration.calibrate import Calibrator
    from grassd.daemon.core.calibration.simulation import simulate_curve
    from grassd.daemon.core.config.settings import load_default_config
    from grassd.sim.light_input import LightInput
    from grassd.sim.scene import RenderSettings, Viewpoint

    status, body = studio.request("api/characteristic", GOOD)
    assert status == 200, body
    cfg = load_default_config()
    display, centre = Calibrator(cfg).display()
    lighting = LightInput(shared_hdri("courtyard"), 5000.0).lighting()
    settings = RenderSettings(samples=cfg.simulation.samples,
                              replicates=cfg.calibration.replicates, seed=cfg.simulation.seed)
    c = simulate_curve(renderer, display, lighting, Viewpoint(170, 2, 0),
                       np.array(GOOD["lengths_mm"], float), settings, pixel_index=centre)
    assert body["replicates"] == cfg.calibration.replicates
    np.testing.assert_allclose(body["ogcd"], c.ogcd, atol=1e-4)
    np.testing.assert_allclose(body["ogcd_stderr"], c.ogcd_stderr, atol=1e-5)


@pytest.mark.parametrize(("change", "words"), [
    ({"ambient_lux": 5e9}, "ambient_lux = 5e+09 is out of range"),
    ({"ambient_lux": "bright"}, "ambient_lux must be a number"),
    ({"viewpoint": [-20, 2, 0]}, "behind the display"),
    ({"viewpoint": [170, 2]}, "viewpoint must be [h_cm, d_m, theta_deg]"),
    ({"viewpoint": [170, 2, 270]}, "theta must be in [-180, 180]"),
    ({"lengths_mm": [0, 25]}, "outside 0..20 mm"),
    ({"light": "nowhere"}, "light 'nowhere' is not one of"),
    ({"sun_lux": 30000}, "sun_lux needs sun_azimuth_deg"),
    ({"target_stderr": 0.0}, "target_stderr = 0 is out of range"),
])
def test_bad_characteristic_requests_get_a_400_naming_the_value(studio, change, words):
    status, body = studio.request("api/characteristic", {**GOOD, **change})
    assert status == 400
    assert words in body["error"]


def test_bad_uploads_get_a_4xx_and_the_server_keeps_serving(studio):
    status, body = studio.request("api/characteristic", b"{not json")
    assert status == 400 and body["error"].startswith("the body must be JSON (")
    status, body = studio.request("api/hdri?name=broken.exr", b"\x76\x2f\x31\x01" + b"x" * 500)
    assert status == 400 and "cannot use broken.exr as the light" in body["error"]
    status, body = studio.request("api/hdri?name=notes.txt", b"hello")
    assert status == 400 and ".exr or .hdr" in body["error"]
    status, body = studio.request("api/picture", b"GIF89a not really")
    assert status == 400 and "cannot show that picture" in body["error"]
    status, body = studio.request("api/picture", b"\0" * (9 * 2**20))
    assert status == 413 and "at most 8 MiB" in body["error"]
    status, body = studio.request("api/characteristic", {**GOOD, "light": []})
    assert status == 400 and "light [] is not one of" in body["error"]
    status, body = studio.request("api/characteristic", {**GOOD, "ambient_lux": 10**400})
    assert status == 400 and "out of range: give 0.001 to 200000 lx" in body["error"]
    # another site's page may not drive the studio (no token on 127.0.0.1)
    status, body = studio.request("api/characteristic", GOOD,
                                  headers={"Origin": "http://evil.example"})
    assert status == 403 and "http://evil.example are refused" in body["error"]
    status, body = studio.request("api/state")
    assert status == 200 and [s["name"] for s in body["lights"]] == ["file"]
    assert studio.request("api/characteristic", GOOD)[0] == 200
    assert studio.proc.poll() is None


def test_an_uploaded_hdri_becomes_a_light(studio, tmp_path, shared_hdri):
    from grassd.sim.hdri import downsample, load_hdri, write_hdr

    path = tmp_path / "small.hdr"
    write_hdr(path, downsample(load_hdri(shared_hdri("forest")), 4))
    status, body = studio.request("api/hdri?name=small.hdr", path.read_bytes())
    assert status == 200, body
    name = body["light"]["name"]
    assert name.startswith("upload:") and body["light"]["label"] == "uploaded: small.hdr"
    status, lit = studio.request("api/characteristic", {**GOOD, "light": name})
    status0, base = studio.request("api/characteristic", GOOD)
    assert status == status0 == 200
    assert lit["ogcd"] != base["ogcd"]  # another light, another characteristic


def test_the_websocket_streams_the_views_and_newer_inputs_supersede(studio):
    status, pic = studio.request("api/picture", png_bytes(np.tile(np.linspace(0, 255, 16), (8, 1))))
    assert status == 200 and (pic["rows"], pic["cols"]) == (4, 8)
    assert pic["rgb"][0][0][1] < 40 and pic["rgb"][0][-1][1] > 215  # box-filtered to 4 x 8
    old = {"type": "inputs", "id": 1, "condition": {"ambient_lux": 5000, "viewpoint": [170, 2, 0]}}
    new = {"type": "inputs", "id": 2, "condition": {
        "ambient_lux": 8000, "viewpoint": [160, 3, 25], "image": pic["image"],
        "sun": {"mode": "site", "lux": 30000, "when": "2026-06-21T12:00"}}}
    got = asyncio.run(ws_session(studio.url, [old, new], until_id=2))
    mine = [m for m in got if m["id"] == 2]
    kinds = [m["type"] for m in mine]
    assert not any(m["type"] == "done" for m in got if m["id"] == 1)  # superseded
    assert kinds[0] == "light" and kinds[1] == "curve" and kinds[2] == "pixel", kinds
    assert {"table", "contrast", "display", "audience"} <= set(kinds) and kinds[-1] == "done"
    light = mine[0]
    # site 35 N 139 E, Asia/Tokyo: solar noon at about 11:45, the sun high in the south
    assert 150 < light["sun"]["azimuth_deg"] < 210 and light["sun"]["elevation_deg"] > 70
    curves = [m for m in mine if m["type"] == "curve"]
    assert curves[0]["replicates"] == 4 and not curves[0]["converged"]
    assert curves[-1]["converged"] and curves[-1]["max_stderr"] <= 0.1
    assert [c["replicates"] for c in curves] == sorted(c["replicates"] for c in curves)
    assert [m["ms"] for m in mine] == sorted(m["ms"] for m in mine)
    table = next(m for m in mine if m["type"] == "table")
    assert table["source"] == "live" and table["r2_after"] > table["r2_before"]
    assert len(table["lengths_mm"]) == 256 and table["lengths_mm"] == sorted(table["lengths_mm"])
    contrast = next(m for m in mine if m["type"] == "contrast")
    assert contrast["distinct_levels"] == int(contrast["ogcd_range"]) + 1
    audience = next(m for m in mine if m["type"] == "audience")
    assert len(audience["places"]) >= 20 and audience["h_cm"] == 160
    pixels = [m for m in mine if m["type"] == "pixel"]
    assert pixels[0]["width"] == 96 and pixels[-1]["spp"] > pixels[0]["spp"]
    assert all(m["image"].startswith("data:image/png;base64,") for m in pixels)


def test_a_characteristic_seen_before_is_sent_once_and_marked_kept(studio):
    """Only the length shown changed: the converged curve of the earlier input comes back at
    once, marked as kept (the page then says so rather than "converged in 1 ms")."""
    cond = {"ambient_lux": 6000, "viewpoint": [150, 2.5, -12], "length_mm": 8}
    first = asyncio.run(ws_session(studio.url, [{"type": "inputs", "id": 31, "condition": cond}],
                                   until_id=31))
    again = asyncio.run(ws_session(studio.url, [{"type": "inputs", "id": 32, "condition": {
        **cond, "length_mm": 14}}], until_id=32))
    fresh = [m for m in first if m["type"] == "curve"]
    kept = [m for m in again if m["type"] == "curve"]
    assert len(fresh) > 1 and not any(m["kept"] for m in fresh)
    assert len(kept) == 1 and kept[0]["kept"] and kept[0]["converged"]
    assert kept[0]["ogcd"] == fresh[-1]["ogcd"] and again[-1]["type"] == "done"


def test_a_bad_input_over_the_websocket_is_an_error_message(studio):
    bad = {"type": "inputs", "id": 7, "condition": {"ambient_lux": 5000,
                                                     "viewpoint": [170, 2, 0],
                                                     "sun": {"mode": "measured"}}}
    got = asyncio.run(ws_session(studio.url, [bad], until_id=7))
    assert got[-1]["type"] == "error" and "has no measured sun" in got[-1]["message"]
    assert studio.request("api/characteristic", GOOD)[0] == 200
    # the condition pinned as B is checked as A's is, said as B's, and A goes on
    behind = {"type": "inputs", "id": 8, "condition": GOOD,
              "pinned": {"ambient_lux": 5000, "viewpoint": [-10, 2, 0]}}
    got = asyncio.run(ws_session(studio.url, [behind], until_id=8))
    pinned = [m for m in got if m["type"] == "pinned"]
    assert len(pinned) == 1 and "behind the display" in pinned[0]["error"], pinned
    assert got[-1]["type"] == "done"


@pytest.fixture(scope="module")
def remote_studio(tmp_path_factory, shared_hdri):
    """A studio on 127.0.0.2 (so with a token) given a fit result: pink green blades."""
    hdri = shared_hdri("courtyard")
    tmp = tmp_path_factory.mktemp("remote")
    (tmp / "pixel.toml").write_text("[display.pixel]\ngreen_srgb = [214.0, 96.0, 170.0]\n"
                                    "splay_deg = 6.0\n")
    s = start_studio(tmp, "--hdri", str(hdri), "--host", "127.0.0.2",
                     "--pixel", str(tmp / "pixel.toml"))
    yield s
    stop_studio(s)


def test_another_address_needs_the_printed_token(remote_studio):
    s = remote_studio
    assert s.url.startswith("http://127.0.0.2:") and len(s.token) >= 20
    status, body = s.request("api/state")
    assert status == 401 and "needs its token" in body["error"]
    assert s.request("api/state", headers={"X-Grassd-Token": "wrong"})[0] == 401
    assert s.request("api/state", headers={"X-Grassd-Token": s.token})[0] == 200
    assert s.request(f"api/state?token={s.token}")[0] == 200
    assert s.request("api/characteristic", GOOD)[0] == 401


def test_a_fit_result_is_the_default_pixel_and_the_config_stays_a_choice(remote_studio):
    s, auth = remote_studio, {"X-Grassd-Token": remote_studio.token}
    _, state = s.request("api/state", headers=auth)
    pixel = state["pixel"]
    assert pixel["default"] == "fit" and pixel["source"] == "fit: pixel.toml"
    assert pixel["choices"]["fit"]["green_srgb"] == [214.0, 96.0, 170.0]
    assert pixel["choices"]["fit"]["splay_deg"] == 6.0
    assert pixel["choices"]["config"]["green_srgb"] == [62.0, 118.0, 46.0]
    fit = s.request("api/characteristic", {**GOOD, "target_stderr": 0.2}, headers=auth)[1]
    config = s.request("api/characteristic", {**GOOD, "target_stderr": 0.2, "pixel": "config"},
                       headers=auth)[1]
    assert abs(fit["ogcd"][-1] - config["ogcd"][-1]) > 3  # another green, another range
    status, body = s.request("api/characteristic", {**GOOD, "pixel": "mine"}, headers=auth)
    assert status == 400 and "pixel must be" in body["error"]


def test_a_simulator_that_dies_is_started_again(studio):
    import os
    import signal
    import time

    _, state = studio.request("api/state")
    pid = state["simulator"]["pid"]
    os.kill(pid, signal.SIGKILL)
    deadline = time.monotonic() + 30
    while studio.request("api/state")[1]["simulator"]["alive"]:
        assert time.monotonic() < deadline, "the server did not notice its simulator died"
        time.sleep(0.1)
    status, body = studio.request("api/characteristic", GOOD)
    assert status == 200, body
    _, state = studio.request("api/state")
    assert state["simulator"]["restarts"] == 1 and state["simulator"]["pid"] != pid
    assert studio.proc.poll() is None


def test_every_address_prints_a_url_with_this_machines_name(tmp_path, shared_hdri):
    """``--host 0.0.0.0`` listens on every address; no machine can open 0.0.0.0, so the URL
    names this machine."""
    import os
    import socket
    import subprocess
    import sys

    from grassd.rigs.processes import end_process

    proc = subprocess.Popen([sys.executable, "-m", "grassd.daemon.cli", "studio", "--port", "0",
                             "--host", "0.0.0.0", "--hdri", str(shared_hdri("courtyard"))],
                            stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
                            env=dict(os.environ, PYTHONUNBUFFERED="1"))
    try:
        line = proc.stdout.readline()
    finally:
        end_process(proc, 15)
    assert line.startswith(f"grassd studio: http://{socket.gethostname()}:"), line
    assert "?token=" in line and "0.0.0.0" not in line


def test_a_scripts_long_request_gives_way_to_a_page(studio):
    """A characteristic that takes many seconds (64 splayed lengths in a low sun) does not hold
    a page's inputs back: the page's views come while it waits, and it goes on after them to
    its target."""
    import threading

    costly = costly_condition(0.05, 30)
    reply: list = []
    script = threading.Thread(target=lambda: reply.append(
        studio.request("api/characteristic", costly)))
    script.start()
    try:
        import time

        time.sleep(2.0)  # the script's job is running
        got = asyncio.run(ws_session(studio.url, [{"type": "inputs", "id": 1,
                                                   "condition": GOOD}], until_id=1))
        assert got[-1]["type"] == "done" and script.is_alive()  # the page did not wait
    finally:
        script.join(300)
    status, body = reply[0]
    assert status == 200, body
    assert max(body["ogcd_stderr"]) <= 0.05 and len(body["ogcd"]) == 64
