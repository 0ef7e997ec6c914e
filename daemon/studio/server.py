"""The studio's web server (aiohttp): the page and its assets (all served from the package, so
the studio works offline on site), a JSON API that scripts and tests use as the page does, and a
WebSocket per page over which the views stream as they refine.

aiohttp rather than an ASGI framework plus a server: one well-kept dependency gives the HTTP
server, WebSockets and the test client, and it runs in the command's own event loop.

API (JSON; a bad value gets a 4xx with ``{"error": message}`` and the server keeps serving; a
condition's unknown keys are refused, and a null is the key left out):

- ``GET /api/state``: the display, site, lights, pixel, viewpoints and audience region.
- ``POST /api/characteristic``: ``ambient_lux``, ``viewpoint`` [h_cm, d_m, theta_deg],
  ``lengths_mm``, optional ``target_stderr``, ``sun_lux``, ``sun_azimuth_deg``,
  ``sun_elevation_deg`` (as in a bundle manifest), ``light``, ``pixel``, ``splay_deg`` ->
  ``lengths_mm``, ``ogcd``, ``ogcd_stderr``, ``replicates``, ``seconds``. Without
  ``target_stderr`` it is the daemon's own simulation (``[simulation] samples`` x
  ``[calibration] replicates``).
- ``POST /api/hdri?name=FILE.exr`` (the file as the body): a new light source.
- ``POST /api/picture`` (a PNG/JPEG as the body): a picture for the display view.
- ``GET /ws``: send ``{"type": "inputs", "id": n, "condition": {...}}`` (and optionally
  ``"pinned": {...}``, the condition shown beside it as B, whose views follow this one's);
  receive ``light``, ``curve``, ``pixel``, ``table``, ``contrast``, ``display``, ``audience``,
  ``pinned`` (B's converged ``curve`` with its ``ogcd_range``, then its image; or an ``error``
  where B cannot be computed, and A goes on), ``done`` and ``error`` messages tagged with that
  ``id`` (those of the job with ``ms`` since it started; an input refused before it, not). A
  refined image (``pixel``, ``pinned``) says ``final`` once it has all its passes.

Bound to 127.0.0.1 by default; on any other address every request needs the token printed at
start (``?token=`` on the page's URL, which sets a cookie, or an ``X-Grassd-Token`` header).
"""

from __future__ import annotations

import asyncio
import contextlib
import hmac
import itertools
import json
import logging
import signal
import time
from importlib import resources
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

from aiohttp import WSMsgType, web

from grassd.daemon.studio.inputs import StudioInputError
from grassd.daemon.studio.lights import MAX_HDRI_BYTES, LightSource
from grassd.daemon.studio.process import SimulatorProcess, StudioArgs
from grassd.daemon.studio.session import Studio, curve_message
from grassd.daemon.studio.views import MAX_IMAGE_BYTES
from grassd.daemon.studio.worker import Superseded

log = logging.getLogger(__name__)

#: Owners of simulator jobs: one per page and per API request.
_OWNERS = itertools.count(1)
#: The address the studio binds unless told otherwise: this computer only, no token.
LOCAL_HOST: str = "127.0.0.1"
COOKIE = "grassd_studio_token"
STUDIO: web.AppKey[Studio] = web.AppKey("studio", Studio)
SIMULATOR: web.AppKey[SimulatorProcess] = web.AppKey("simulator", SimulatorProcess)
TOKEN: web.AppKey[str | None] = web.AppKey("token", str)
SOCKETS: web.AppKey[set] = web.AppKey("sockets", set)
#: Seconds the studio waits at its end for requests in flight (a page's socket is closed).
SHUTDOWN_S: float = 2.0


def static_dir() -> Path:
    """The page and its vendored assets (package data)."""
    return Path(str(resources.files("grassd.daemon.studio").joinpath("static")))


def _error(status: int, message: str) -> web.Response:
    return web.json_response({"error": message}, status=status)


@web.middleware
async def _guard(request: web.Request, handler):
    """The origin and token checks and JSON errors for every failure. A request a browser sends
    from another site's page (its Origin is not this server) is refused: without it, any page
    the user visits could drive a studio on 127.0.0.1 and upload into it."""
    origin = request.headers.get("Origin")
    try:
        origin_host = None if origin is None else urlsplit(origin).netloc
        host_name = urlsplit(f"//{request.host}").hostname
    except ValueError:  # e.g. "[" or "[::1" as a Host
        return _error(400, "the request's Host or Origin header is not a host name")
    if origin is not None and origin_host != request.host:
        return _error(403, f"requests from {origin[:80]} are refused: open the studio's own "
                           f"page")
    token = request.app[TOKEN]
    if token is None and host_name not in LOCAL_NAMES:
        return _error(403, f"this studio answers as 127.0.0.1 or localhost only, not as "
                           f"{request.host[:80]}: open the URL it printed at start")
    if token is not None:
        given = (request.query.get("token") or request.headers.get("X-Grassd-Token")
                 or request.cookies.get(COOKIE) or "")
        if not hmac.compare_digest(given.encode(), token.encode()):
            return _error(401, "this studio needs its token: open the URL it printed at start "
                               "(…/?token=…)")
    try:
        response = await handler(request)
    except web.HTTPRequestEntityTooLarge as exc:
        return _error(413, f"the upload is too large ({exc.text})")
    except web.HTTPException as exc:
        if exc.status >= 400:
            return _error(exc.status, exc.reason)
        raise
    if token is not None and request.query.get("token") == token:
        response.set_cookie(COOKIE, token, httponly=True, samesite="Strict")
    return response


async def _index(request: web.Request) -> web.StreamResponse:
    return web.FileResponse(static_dir() / "index.html",
                            headers={"Cache-Control": "no-cache"})


async def _state(request: web.Request) -> web.Response:
    sim = request.app[SIMULATOR]
    return web.json_response({**request.app[STUDIO].state(),
                              "simulator": {"pid": sim.proc.pid, "alive": sim.alive,
                                            "restarts": sim.restarts}})


#: What parsing a WebSocket request may raise on a bad value (the message says which).
_BAD_INPUT = (ValueError, TypeError, OverflowError, StudioInputError)
#: Most bytes of a JSON request or WebSocket message (a condition is well under 10 KiB).
MAX_JSON_BYTES: int = 1 << 20
#: The names a studio on 127.0.0.1 answers to: a page of another name reaching it (a DNS name
#: rebound to 127.0.0.1, whose Origin then matches its Host) is refused.
LOCAL_NAMES: frozenset[str] = frozenset({"127.0.0.1", "localhost", "::1"})


def parse_json(text: str | bytes, what: str = "the body") -> Any:
    """``text`` decoded as JSON; StudioInputError saying why where it is not (too deeply
    nested, or an integer of more digits than Python converts, included)."""
    try:
        return json.loads(text)
    except RecursionError:
        raise StudioInputError(f"{what} is nested too deeply to be a request") from None
    except (ValueError, UnicodeDecodeError) as exc:  # JSONDecodeError and integer limits
        raise StudioInputError(f"{what} must be JSON ({exc})") from None


async def _json_body(request: web.Request) -> Any:
    return parse_json(await _read_capped(request, MAX_JSON_BYTES, "a JSON request"))


async def _characteristic(request: web.Request) -> web.Response:
    studio = request.app[STUDIO]
    try:
        data = await _json_body(request)
        cond = studio.parse(data)
        target = data.get("target_stderr")
        if target is None:
            kw = dict(target_stderr=None, samples=studio.cfg.simulation.samples,
                      replicates=studio.cfg.calibration.replicates)
        else:
            kw = dict(target_stderr=cond.target_stderr)
    except StudioInputError as exc:
        return _error(400, str(exc))
    t0 = time.perf_counter()
    simulator, owner = request.app[SIMULATOR], next(_OWNERS)
    try:
        curve = await simulator.submit(owner, "characteristic", (cond, kw))
    except asyncio.CancelledError:  # the client went away: its job stops too
        simulator.cancel(owner)
        raise
    except StudioInputError as exc:
        return _error(400, str(exc))
    except RuntimeError as exc:  # the renderer failed: said, the studio goes on
        return _error(500, str(exc))
    msg = curve_message(curve, kw["target_stderr"])
    out = {k: msg[k] for k in ("lengths_mm", "ogcd", "ogcd_stderr", "replicates")}
    out["seconds"] = round(time.perf_counter() - t0, 4)
    return web.json_response(out)


async def _read_capped(request: web.Request, limit: int, what: str) -> bytes:
    if request.content_length is not None and request.content_length > limit:
        raise web.HTTPRequestEntityTooLarge(max_size=limit, actual_size=request.content_length,
                                            text=f"{what}: at most {limit // 2**20} MiB")
    chunks, size = [], 0
    async for chunk in request.content.iter_chunked(1 << 16):  # to the end of the body
        size += len(chunk)
        if size > limit:
            raise web.HTTPRequestEntityTooLarge(max_size=limit, actual_size=size,
                                                text=f"{what}: at most {limit // 2**20} MiB")
        chunks.append(chunk)
    return b"".join(chunks)


async def _hdri(request: web.Request) -> web.Response:
    studio = request.app[STUDIO]
    data = await _read_capped(request, MAX_HDRI_BYTES, "an HDRI")
    name = request.query.get("name", "")
    loop = asyncio.get_running_loop()

    async def add() -> LightSource:  # both lists get it, even if the client goes away
        src = await loop.run_in_executor(None, studio.lights.add_upload, name, data)
        request.app[SIMULATOR].add_light(src)  # its file: only the simulator renders it
        return src

    try:
        src = await asyncio.shield(add())
    except StudioInputError as exc:
        return _error(400, str(exc))
    return web.json_response({"light": src.describe(), "lights": studio.lights.describe()})


async def _picture(request: web.Request) -> web.Response:
    studio = request.app[STUDIO]
    if request.content_type.startswith("multipart/"):
        return _error(400, "send the picture's own bytes as the request's body, not a form "
                           "(curl --data-binary @picture.png)")
    data = await _read_capped(request, MAX_IMAGE_BYTES, "a picture")
    loop = asyncio.get_running_loop()
    try:  # decoding a large picture takes a while: not on the event loop
        return web.json_response(await loop.run_in_executor(None, studio.add_picture, data))
    except StudioInputError as exc:
        return _error(400, str(exc))


#: What a page sends over the WebSocket (said to one that sends something else).
_WS_FORM = 'send text messages {"type": "inputs", "id": n, "condition": {...}}'


async def _socket(request: web.Request) -> web.WebSocketResponse:
    """One page: its latest inputs run on the simulator, the views stream back."""
    studio, simulator = request.app[STUDIO], request.app[SIMULATOR]
    ws = web.WebSocketResponse(heartbeat=30.0, max_msg_size=MAX_JSON_BYTES)
    await ws.prepare(request)
    request.app[SOCKETS].add(ws)
    owner = next(_OWNERS)
    outbox: asyncio.Queue = asyncio.Queue()

    async def sender() -> None:
        while True:
            msg = await outbox.get()
            if ws.closed:
                return
            await ws.send_json(msg)

    def finished(fut: asyncio.Future, tag: int) -> None:
        exc = None if fut.cancelled() else fut.exception()
        if isinstance(exc, StudioInputError) or (exc is not None
                                                 and not isinstance(exc, Superseded)):
            outbox.put_nowait({"type": "error", "id": tag, "message": str(exc)})

    task = asyncio.create_task(sender())
    try:
        async for m in ws:
            if m.type == WSMsgType.BINARY:
                outbox.put_nowait({"type": "error", "id": 0, "message": _WS_FORM})
                continue
            if m.type != WSMsgType.TEXT:
                continue
            tag = 0
            try:
                data = parse_json(m.data, "a message")
                if not isinstance(data, dict) or data.get("type") != "inputs":
                    raise StudioInputError(_WS_FORM)
                tag = data.get("id", 0)
                if isinstance(tag, bool) or not isinstance(tag, int):
                    tag = 0
                    raise StudioInputError(f"{_WS_FORM}: the id is an integer")
                cond = studio.parse(data.get("condition"))
                levels = studio.picture(cond.image)
            except _BAD_INPUT as exc:
                simulator.cancel(owner)
                outbox.put_nowait({"type": "error", "id": tag, "message": str(exc)})
                continue
            pinned = data.get("pinned")  # the condition shown beside it as B
            if pinned is not None:
                try:
                    pinned = studio.parse(pinned)
                except _BAD_INPUT as exc:
                    outbox.put_nowait({"type": "pinned", "id": tag, "error": str(exc),
                                       "final": True})  # said as B's; A goes on
                    pinned = None

            def emit(msg: dict[str, Any], tag: int = tag) -> None:
                msg["id"] = tag
                outbox.put_nowait(msg)

            fut = simulator.submit(owner, "views", (cond, levels, pinned), emit)
            fut.add_done_callback(lambda f, tag=tag: finished(f, tag))
    finally:
        request.app[SOCKETS].discard(ws)
        simulator.cancel(owner)
        task.cancel()
    return ws


async def _close_sockets(app: web.Application) -> None:
    """At the studio's end: close every page's socket (it would hold the end up otherwise)."""
    for ws in list(app[SOCKETS]):
        await ws.close(code=1001, message=b"the studio is stopping")


def make_app(studio: Studio, simulator: SimulatorProcess,
             token: str | None = None) -> web.Application:
    """The studio's aiohttp application (the page, the API, the WebSocket)."""
    app = web.Application(middlewares=[_guard], client_max_size=MAX_HDRI_BYTES + 2**20)
    app[STUDIO] = studio
    app[SIMULATOR] = simulator
    app[TOKEN] = token
    app[SOCKETS] = set()
    app.on_shutdown.append(_close_sockets)
    app.router.add_get("/", _index)
    app.router.add_get("/api/state", _state)
    app.router.add_post("/api/characteristic", _characteristic)
    app.router.add_post("/api/hdri", _hdri)
    app.router.add_post("/api/picture", _picture)
    app.router.add_get("/ws", _socket)
    app.router.add_static("/static/", static_dir(), append_version=False)
    return app


async def serve(args: StudioArgs, host: str, port: int, token: str | None,
                ready: asyncio.Future | None = None) -> None:
    """Serve the studio ``args`` describe until cancelled or sent SIGTERM (uploads removed,
    the simulator stopped either way); ``ready`` gets the bound (host, port). The simulations
    run in a child process (:mod:`.process`)."""
    studio = args.build()

    def warmed(seconds: float) -> None:
        studio.ready = True
        log.info("studio warmed up in %.1f s", seconds)

    simulator = SimulatorProcess(args, warmed)
    # handler_cancellation: a request whose client went away is cancelled, and so its job
    runner = web.AppRunner(make_app(studio, simulator, token), access_log=None,
                           handler_cancellation=True, shutdown_timeout=SHUTDOWN_S)
    stop = asyncio.Event()  # SIGTERM (systemd, kill) ends it as Ctrl-C does: cleaned up
    loop = asyncio.get_running_loop()
    with contextlib.suppress(NotImplementedError, RuntimeError):  # no signals off the main
        loop.add_signal_handler(signal.SIGTERM, stop.set)  # thread
    try:
        await runner.setup()
        site = web.TCPSite(runner, host, port, shutdown_timeout=SHUTDOWN_S)
        await site.start()
        bound = site._server.sockets[0].getsockname()[:2]  # the port the OS chose for port 0
        if ready is not None:
            ready.set_result(bound)
        await stop.wait()
    finally:
        with contextlib.suppress(NotImplementedError, RuntimeError):
            loop.remove_signal_handler(signal.SIGTERM)
        try:
            await runner.cleanup()
        finally:
            simulator.stop()
            studio.lights.cleanup()


__all__ = ["LOCAL_HOST", "make_app", "serve", "static_dir"]
