"""Requests no page sends, against a real ``grassd studio`` process: each gets a 4xx (or a
WebSocket error message) saying what to send instead, and the server goes on serving; a request
whose client goes away stops its job, and SIGTERM ends the studio as Ctrl-C does."""

from __future__ import annotations

import asyncio
import json
import signal
import socket
import time
import urllib.parse

from conftest import GOOD, costly_condition, start_studio


def test_malformed_json_gets_a_400_saying_why(studio):
    status, body = studio.request("api/characteristic", b"[" * 100_000 + b"]" * 100_000)
    assert status == 400 and "nested too deeply" in body["error"]
    status, body = studio.request("api/characteristic", b'{"ambient_lux": ' + b"9" * 5000
                                  + b"}")
    assert status == 400 and body["error"].startswith("the body must be JSON (")
    status, body = studio.request("api/characteristic",
                                  {**GOOD, "pad": "x" * (2 << 20)})
    assert status == 413 and "a JSON request: at most 1 MiB" in body["error"]
    assert studio.request("api/characteristic", GOOD)[0] == 200


def test_a_request_to_the_local_studio_under_another_name_is_refused(studio):
    """A site whose name is rebound to 127.0.0.1 sends its own name as Host and Origin."""
    port = urllib.parse.urlsplit(studio.url).port
    evil = f"evil.example:{port}"
    status, body = studio.request("api/characteristic", GOOD,
                                  headers={"Host": evil, "Origin": f"http://{evil}"})
    assert status == 403 and "answers as 127.0.0.1 or localhost only" in body["error"]
    assert studio.request("api/state", headers={"Host": f"localhost:{port}"})[0] == 200
    status, body = studio.request("api/state", headers={"Host": "[::1"})
    assert status == 400 and "not a host name" in body["error"]


def test_picture_uploads_that_are_no_picture_say_what_to_send(studio):
    status, body = studio.request("api/picture", b"")
    assert status == 400 and "the body is empty" in body["error"]
    status, body = studio.request("api/picture", b"--x\r\n\r\n", headers={
        "Content-Type": "multipart/form-data; boundary=x"})
    assert status == 400 and "not a form" in body["error"]
    status, body = studio.request("api/picture", b"plain text, not a picture")
    assert status == 400 and "(PNG, JPEG, ...)" in body["error"]
    assert "BytesIO" not in body["error"]


def test_active_tables_need_a_studio_that_has_one(studio):
    status, body = studio.request("api/characteristic", {**GOOD, "tables": "active"})
    assert status == 400 and "has no active table" in body["error"]


async def _socket_replies(url: str) -> list[dict]:
    import aiohttp

    good = {"type": "inputs", "id": 5, "condition": GOOD}
    got = []
    async with aiohttp.ClientSession() as s, s.ws_connect(url.replace("http", "ws") + "ws") as ws:
        await ws.send_bytes(b"\x00\x01")
        await ws.send_str(json.dumps({**good, "id": "abc"}))
        await ws.send_str("[" * 50_000 + "]" * 50_000)
        await ws.send_str(json.dumps(good))
        async with asyncio.timeout(120):
            async for m in ws:
                got.append(json.loads(m.data))
                if got[-1]["id"] == 5 and got[-1]["type"] in ("done", "error"):
                    break
    return got


def test_the_websocket_says_what_to_send_and_goes_on(studio):
    got = asyncio.run(_socket_replies(studio.url))
    errors = [m["message"] for m in got if m["type"] == "error"]
    assert errors[0].startswith('send text messages {"type": "inputs"')
    assert "the id is an integer" in errors[1]
    assert "nested too deeply" in errors[2]
    assert got[-1] == {"type": "done", "id": 5, "ms": got[-1]["ms"]}


def test_a_request_whose_client_goes_away_stops_its_job(studio):
    """A request that would take many seconds (64 lengths to 0.05 dE00 of splayed blades in
    a low sun, under the studio's cost cap) is left after a second; the next request does not
    wait for it."""
    costly = costly_condition(0.05, 45)
    body = json.dumps(costly).encode()
    url = urllib.parse.urlsplit(studio.url)
    with socket.create_connection((url.hostname, url.port)) as conn:
        conn.sendall(b"POST /api/characteristic HTTP/1.1\r\nHost: 127.0.0.1\r\n"
                     b"Content-Type: application/json\r\n"
                     + f"Content-Length: {len(body)}\r\n\r\n".encode() + body)
        time.sleep(1.0)
    t0 = time.monotonic()
    status, reply = studio.request("api/characteristic", GOOD)
    assert status == 200, reply
    assert time.monotonic() - t0 < 20, "the request waited for the abandoned one"


async def _page_until_closed(url: str, opened) -> str:
    """Open a page's socket, send an input, and read until the studio closes it."""
    import aiohttp

    async with aiohttp.ClientSession() as s, s.ws_connect(url.replace("http", "ws") + "ws") as ws:
        await ws.send_str(json.dumps({"type": "inputs", "id": 1, "condition": GOOD}))
        opened.set()
        async with asyncio.timeout(120):
            async for _m in ws:
                pass
        return ws.close_code


def test_sigterm_with_a_page_open_removes_the_uploads_and_ends_the_studio(tmp_path,
                                                                          shared_hdri):
    """Within systemd's stop timeout: an open page's socket is closed rather than waited for
    (aiohttp waits 60 s for each request in flight by default)."""
    import threading

    from grassd.sim.hdri import downsample, load_hdri, write_hdr

    tmp = tmp_path / "tmp"
    tmp.mkdir()
    s = start_studio(tmp_path, "--hdri", str(shared_hdri("courtyard")), env={"TMPDIR": str(tmp)})
    try:
        path = tmp_path / "small.hdr"
        write_hdr(path, downsample(load_hdri(shared_hdri("forest")), 4))
        assert s.request("api/hdri?name=small.hdr", path.read_bytes())[0] == 200
        assert [p.name.startswith("grassd-studio-") for p in tmp.iterdir()] == [True]
        opened, closed = threading.Event(), []
        page = threading.Thread(target=lambda: closed.append(
            asyncio.run(_page_until_closed(s.url, opened))))
        page.start()
        assert opened.wait(30)
        t0 = time.monotonic()
        s.proc.send_signal(signal.SIGTERM)
        assert s.proc.wait(timeout=60) == 0, s.log.read_text()
        assert time.monotonic() - t0 < 30  # systemd's TimeoutStopSec is 90 s
        page.join(30)
        assert closed == [1001]  # "going away", said by the studio
        assert list(tmp.iterdir()) == []
    finally:
        if s.proc.poll() is None:
            s.proc.kill()
