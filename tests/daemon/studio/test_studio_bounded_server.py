"""The studio as a bounded server, against a real ``grassd studio`` process: a connection
that never finishes its headers, a page's socket that never reads, uploads kept or decoded
beyond the caps and pages asking costly inputs are each refused with a reason, while another
page is served; where the attack is on memory, the studio's peak resident set (VmHWM) stays
under 300 MiB."""

from __future__ import annotations

import asyncio
import json
import socket
import time
from pathlib import Path

import numpy as np
import pytest
from conftest import GOOD, costly_condition, png_bytes, start_studio, stop_studio, ws_session

from grassd.daemon.studio.limits import DEFAULT_LIMITS
from grassd.rigs.hostile_studio import (
    address,
    answers,
    at_once,
    close_of,
    header_flood,
    never_reading_page,
    post_headers,
    read_until_closed,
    unfinished_headers,
)
from grassd.rigs.peak_memory import proc_mib

#: The peak resident set (MiB) the studio's server process stays under in every attack.
PEAK_MIB = 300


def _page_is_served(studio, within_s: float = 60) -> float:
    """Seconds a page's input takes to its ``done`` (asserting it comes)."""
    t0 = time.monotonic()
    got = asyncio.run(ws_session(studio.url, [{"type": "inputs", "id": 1, "condition": GOOD}],
                                 until_id=1, timeout_s=within_s))
    assert got[-1]["type"] == "done", got[-1]
    return time.monotonic() - t0


# ---------------------------------------------------------------- unfinished headers (row 10)
def test_unfinished_headers_are_cut_and_a_page_is_still_served(studio):
    """1050 connections that each send half a request and wait: the oldest make room for new
    ones (the cap), each is closed within a few seconds with a 408 or 503 saying why, and a
    page's request meanwhile is answered at once."""
    t0 = time.monotonic()
    opened = unfinished_headers(studio.url, 1050)
    t_api = time.monotonic()
    status, state = studio.request("api/state")
    assert status == 200 and state["ready"]
    assert time.monotonic() - t_api < 3
    deadline = t0 + DEFAULT_LIMITS.header_s + 10
    got = answers(opened, deadline)
    assert time.monotonic() < deadline + 1, "unfinished requests were kept open"
    timed_out = [a for a in got if a.startswith(b"HTTP/1.1 408")]
    evicted = [a for a in got if a.startswith(b"HTTP/1.1 503")]
    assert len(timed_out) + len(evicted) == 1050, {a[:12] for a in got}
    assert timed_out and evicted  # the last ones waited for their deadline
    assert b"did not come within 5 s" in timed_out[0]
    assert b"connections open and this one was not being served" in evicted[0]
    assert studio.request("api/state")[0] == 200
    assert proc_mib(studio.proc.pid, "VmHWM") < PEAK_MIB


def test_requests_of_too_many_header_lines_are_refused(studio):
    """300 connections each sending 120 header lines of 8000 bytes: each is answered 400 (more
    lines than the cap) or 503 (room made for a newer one), and a page is answered."""
    conns = header_flood(studio.url, 300)
    assert studio.request("api/state")[0] == 200
    got = answers(conns, time.monotonic() + 10)
    too_many = [a for a in got if a.startswith(b"HTTP/1.0 400")]
    assert too_many and b"Too many headers" in too_many[0]
    assert all(a.startswith((b"HTTP/1.0 400", b"HTTP/1.1 503")) for a in got), \
        {a[:12] for a in got}
    assert proc_mib(studio.proc.pid, "VmHWM") < PEAK_MIB


@pytest.fixture(scope="module")
def open_studio(tmp_path_factory, shared_hdri):
    """A studio bound to every address (so it needs its token), reached on 127.0.0.1."""
    s = start_studio(tmp_path_factory.mktemp("open"), "--host", "0.0.0.0",
                     "--hdri", str(shared_hdri("courtyard")))
    s.url = f"http://127.0.0.1:{address(s.url)[1]}/"
    yield s
    stop_studio(s)


def test_without_its_token_a_request_is_refused_before_its_body(open_studio):
    """A 200 MiB upload announced without the token is answered 401 from its headers alone
    and the connection closed (the body is never waited for); unfinished headers get their
    408 as on 127.0.0.1; with the token the studio answers."""
    host, port = address(open_studio.url)
    with socket.create_connection((host, port)) as c:
        t0 = time.monotonic()
        c.sendall(b"POST /api/hdri?name=big.exr HTTP/1.1\r\nHost: 127.0.0.1\r\n"
                  b"Content-Length: 209715200\r\n\r\n")
        got = read_until_closed(c, 5)
        assert time.monotonic() - t0 < 2
    assert got.startswith(b"HTTP/1.1 401") and b"needs its token" in got
    with socket.create_connection((host, port)) as c:
        t0 = time.monotonic()
        c.sendall(b"GET / HTTP/1.1\r\nHost: 127.0.0.1\r\n")
        got = read_until_closed(c, 15)
        assert time.monotonic() - t0 < DEFAULT_LIMITS.header_s + 2
    assert got.startswith(b"HTTP/1.1 408")
    status, state = open_studio.request("api/state",
                                        headers={"X-Grassd-Token": open_studio.token})
    assert status == 200 and state["ready"]
    assert proc_mib(open_studio.proc.pid, "VmHWM") < PEAK_MIB


def test_a_body_that_stops_coming_gets_a_408(studio):
    """A JSON request whose body stops halfway is answered 408 after the idle deadline."""
    host, port = address(studio.url)
    with socket.create_connection((host, port)) as c:
        t0 = time.monotonic()
        c.sendall(b"POST /api/characteristic HTTP/1.1\r\nHost: 127.0.0.1\r\n"
                  b"Content-Type: application/json\r\nContent-Length: 1000\r\n\r\n{\"ambi")
        got = read_until_closed(c, 30)
        took = time.monotonic() - t0
    assert got.startswith(b"HTTP/1.1 408"), got[:200]
    assert b"nothing came for 10 s" in got
    assert DEFAULT_LIMITS.body_idle_s - 1 < took < DEFAULT_LIMITS.body_idle_s + 5


# ---------------------------------------------------------------- a page that never reads (row 7)
def test_a_page_that_never_reads_is_closed_and_its_memory_freed(studio):
    """A socket that sends up to 200,000 small frames, each answered with an error, and reads
    nothing: its outbox fills, it is closed 1008 saying why (what it was sent before is still
    there to read), the server's peak stays under 300 MiB, and a page is served meanwhile."""
    frames = never_reading_page(
        studio.url, lambda: b"a page's socket was closed" in studio.log.read_bytes())
    close = close_of(frames)
    assert close is not None, f"no close frame in {len(frames)} frames"
    assert close[0] == 1008 and "does not read its messages" in close[1]
    assert _page_is_served(studio) < 60
    assert proc_mib(studio.proc.pid, "VmHWM") < PEAK_MIB


# ---------------------------------------------------------------- uploads (rows 8 and 9)
def _upload_sky(path: Path, level: float, size: tuple[int, int] = (1024, 2048)) -> bytes:
    """A uniform sky of ``level`` as a Radiance .hdr file of ``size`` (rows, cols) texels."""
    from grassd.sim.hdri import write_hdr

    write_hdr(path, np.full((*size, 3), level, np.float32))
    return path.read_bytes()


@pytest.fixture
def upload_studio(tmp_path, shared_hdri):
    """A studio of its own whose temporary folder is ``tmp_path``/tmp."""
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    s = start_studio(tmp_path, "--hdri", str(shared_hdri("courtyard")),
                     env={"TMPDIR": str(tmp)})
    s.tmp = tmp
    yield s
    stop_studio(s)


@pytest.mark.long
def test_uploads_beyond_the_caps_drop_the_oldest_and_their_maps(upload_studio, tmp_path):
    """20 uploaded skies of 2048 x 1024 texels, each lighting one characteristic: the studio
    keeps the newest 4 (listed, their files in its temporary folder), an older one is refused
    as not one of the studio's, and the simulator holds no more maps at the 20th than once
    it holds as many as it keeps."""
    s = upload_studio
    sim = s.simulator_pid()
    kept = DEFAULT_LIMITS.kept_uploads
    rss = []
    for i in range(20):
        body = _upload_sky(tmp_path / f"sky{i}.hdr", 0.5 + i / 20)
        status, reply = s.request(f"api/hdri?name=sky{i}.hdr", body)
        assert status == 200, reply
        name = reply["light"]["name"]
        status, reply = s.request("api/characteristic", {**GOOD, "light": name})
        assert status == 200, reply
        rss.append(proc_mib(sim))
    status, state = s.request("api/state")
    uploads = [light["name"] for light in state["lights"] if light["name"].startswith("upload:")]
    assert len(uploads) == kept
    files = list(next(s.tmp.iterdir()).iterdir())
    assert len(files) == kept
    status, reply = s.request("api/characteristic", {**GOOD, "light": "upload:1"})
    assert status == 400 and "is not one of the studio's" in reply["error"]
    maps = DEFAULT_LIMITS.kept_maps
    assert rss[-1] - rss[maps + 1] < 60, rss  # less than one more map (docs/studio.md)
    assert proc_mib(s.proc.pid, "VmHWM") < PEAK_MIB


def test_uploads_beyond_the_slot_get_a_503_and_one_is_decoded_at_a_time(studio):
    """Four pictures of 4096 x 4096 sent at once: the first takes the upload slot, the other
    three are answered 503 from their headers (their bodies are not read), the first is
    decoded; decoded one at a time, the studio's peak stays under 300 MiB."""
    host, port = address(studio.url)
    ramp = np.add.outer(np.arange(4096), np.arange(4096)) % 256
    picture = png_bytes(np.stack([ramp, ramp.T, 255 - ramp], axis=-1), "RGB")
    conns = [socket.create_connection((host, port)) for _ in range(4)]
    for c in conns:
        c.sendall(post_headers("api/picture", len(picture), "image/png"))
        time.sleep(0.2)  # in this order
    busy = [read_until_closed(c, 10) for c in conns[1:]]
    for a in busy:
        assert a.startswith(b"HTTP/1.1 503"), a[:200]
        assert b"reading another upload (at most 1 at a time)" in a
    status, reply = studio.request("api/hdri?name=sky.exr", b"\x76\x2f\x31\x01")
    assert status == 503 and "reading another upload" in reply["error"]  # one slot for both
    conns[0].sendall(picture)
    first = read_until_closed(conns[0], 60)
    for c in conns:
        c.close()
    assert first.startswith(b"HTTP/1.1 200"), first[:300]
    replies = at_once(lambda: studio.request(  # each answered, none decoded beside another
        "api/picture", picture, headers={"Content-Type": "image/png"}), 4)
    assert sorted(r[0] for r in replies) in ([200, 503, 503, 503], [200, 200, 503, 503],
                                            [200, 200, 200, 503], [200] * 4)
    assert any(r[0] == 200 for r in replies)
    assert _page_is_served(studio) < 60
    assert proc_mib(studio.proc.pid, "VmHWM") < PEAK_MIB


@pytest.fixture(scope="module")
def huge_uploads(tmp_path_factory) -> tuple[bytes, bytes]:
    """(an 8192 x 4096 ZIP EXR, an 8192 x 8192 PNG), both flat: small files, large images."""
    from grassd.sim.hdri import write_exr

    tmp = tmp_path_factory.mktemp("huge")
    write_exr(tmp / "huge.exr", np.full((4096, 8192, 3), 0.5, np.float32), half=True)
    return (tmp / "huge.exr").read_bytes(), png_bytes(np.full((8192, 8192), 140))


def test_large_images_sent_four_at_a_time_keep_the_studio_small(studio, huge_uploads):
    """Four 8192 x 4096 EXRs, then four 8192 x 8192 PNGs, each four at once: every one is
    answered (decoded, refused for its size, or a 503 while the slot is taken), a page is
    served, and the studio's peak stays under 300 MiB."""
    exr, png = huge_uploads
    for path, body, headers in (("api/hdri?name=huge.exr", exr, None),
                                ("api/picture", png, {"Content-Type": "image/png"})):
        replies = at_once(lambda path=path, body=body, headers=headers:
                          studio.request(path, body, headers=headers), 4)
        assert len(replies) == 4
        for status, reply in replies:
            assert status in (200, 400, 503), reply
            if status == 503:
                assert "reading another upload" in reply["error"]
        assert any(status != 503 for status, _ in replies)
    assert _page_is_served(studio) < 60
    assert proc_mib(studio.proc.pid, "VmHWM") < PEAK_MIB


# ---------------------------------------------------------------- costly inputs (row 11)
def test_an_input_beyond_the_cost_cap_is_refused_saying_how_to_lower_it(studio):
    costly = costly_condition(0.02, 45)
    status, body = studio.request("api/characteristic", costly)
    assert status == 400
    assert "the studio runs at most 2000" in body["error"]
    assert "ask for a target_stderr of at least 0.043 dE00 or at most 13 lengths" \
        in body["error"]
    got = asyncio.run(ws_session(studio.url, [{"type": "inputs", "id": 3, "condition": costly}],
                                 until_id=3, timeout_s=30))
    assert got[-1]["type"] == "error" and "this input would cost about 9200 units" \
        in got[-1]["message"]


async def _first_curve_while_busy(url: str, costly: dict) -> tuple[float, list[dict]]:
    """Two pages ask ``costly``; 3 s later a third asks GOOD: seconds to its first curve, and
    its messages to its done."""
    import aiohttp

    async with aiohttp.ClientSession() as s:
        busy = [await s.ws_connect(url.replace("http", "ws") + "ws") for _ in range(2)]
        for ws in busy:
            await ws.send_str(json.dumps({"type": "inputs", "id": 1, "condition": costly}))
        await asyncio.sleep(3.0)
        async with s.ws_connect(url.replace("http", "ws") + "ws") as ws:
            t0 = time.monotonic()
            await ws.send_str(json.dumps({"type": "inputs", "id": 7, "condition": GOOD}))
            first, got = None, []
            async with asyncio.timeout(120):
                async for m in ws:
                    msg = json.loads(m.data)
                    got.append(msg)
                    if msg["type"] == "curve" and first is None:
                        first = time.monotonic() - t0
                    if msg["type"] in ("done", "error"):
                        break
        for ws in busy:
            await ws.close()
    return first, got


def test_pages_take_turns_a_costly_input_does_not_hold_another_page_back(studio):
    """Two pages ask 64 splayed lengths to 0.05 dE00 in a low sun (under the cap, many
    seconds each); a third page's input gets its first curve within a few seconds (0.3 s
    alone) and all its views."""
    first, got = asyncio.run(_first_curve_while_busy(studio.url, costly_condition(0.05, 45)))
    assert got[-1]["type"] == "done", got[-1]
    assert first is not None and first < 8, first
