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
- ``POST /api/picture`` (a PNG/JPEG as the body): a picture for the display view -> its
  ``image`` id and ``rgb``, one sRGB colour per display pixel; the ``display`` message of a
  condition with that ``image`` gives the ``levels`` the daemon would show for it (by
  ``[content] map``, onto the colours named in ``colours``).
- ``GET /ws``: send ``{"type": "inputs", "id": n, "condition": {...}}`` (and optionally
  ``"pinned": {...}``, the condition shown beside it as B, whose views follow this one's);
  receive ``light``, ``curve``, ``pixel``, ``table``, ``contrast``, ``display``, ``audience``,
  ``pinned`` (B's converged ``curve`` with its ``ogcd_range``, then its image; or an ``error``
  where B cannot be computed, and A goes on), ``done`` and ``error`` messages tagged with that
  ``id`` (those of the job with ``ms`` since it started; an input refused before it, not). A
  refined image (``pixel``, ``pinned``) says ``final`` once it has all its passes.

Bound to 127.0.0.1 by default; on any other address every request needs the token printed at
start (``?token=`` on the page's URL, which sets a cookie, or an ``X-Grassd-Token`` header),
checked once the headers are in and before any of the body is read (a refused request's body is
never read: the connection is closed after the answer).

A bounded server (:class:`~grassd.daemon.studio.limits.StudioLimits`): a connection gets a few
seconds for its headers (a 408 and closed after them), its body comes within its own deadlines
(408), the open connections are capped (the oldest waiting for its headers or idle makes room),
a page's outbox is capped (a page that does not read is closed, 1008), uploads are read and
decoded a few at a time (503 beyond; a picture here, an HDRI only in the simulator), and a
characteristic costing more than the cap is refused before it runs
(:mod:`grassd.daemon.studio.cost`).
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
from collections import OrderedDict, deque
from collections.abc import Awaitable, Callable
from concurrent.futures import ThreadPoolExecutor
from importlib import resources
from pathlib import Path
from typing import TypedDict, TypeVar, Unpack
from urllib.parse import urlsplit

from aiohttp import WSMsgType, web
from aiohttp.web_protocol import RequestHandler, _ErrInfo

from grassd.daemon.core.errors import DaemonError
from grassd.daemon.core.runtime.freed_memory import release_freed_memory
from grassd.daemon.studio.cost import check_cost
from grassd.daemon.studio.inputs import Condition, JsonValue, StudioInputError
from grassd.daemon.studio.lights import MAX_HDRI_BYTES, LightSource
from grassd.daemon.studio.limits import DEFAULT_LIMITS, StudioLimits
from grassd.daemon.studio.messages import CharacteristicAnswer, PageMessage, PictureUpload
from grassd.daemon.studio.process import CurveJob, SimulatorProcess, StudioArgs, ViewsJob
from grassd.daemon.studio.session import CharacteristicArgs, Studio, curve_message
from grassd.daemon.studio.views import MAX_IMAGE_BYTES
from grassd.daemon.studio.worker import Superseded

log = logging.getLogger(__name__)

#: Owners of simulator jobs: one per page and per API request.
_OWNERS = itertools.count(1)
_Body = TypeVar("_Body")
_Decoded = TypeVar("_Decoded")
#: The address the studio binds unless told otherwise: this computer only, no token.
LOCAL_HOST: str = "127.0.0.1"
COOKIE = "grassd_studio_token"
STUDIO: web.AppKey[Studio] = web.AppKey("studio", Studio)
SIMULATOR: web.AppKey[SimulatorProcess] = web.AppKey("simulator", SimulatorProcess)
TOKEN: web.AppKey[str | None] = web.AppKey("token", str)
SOCKETS: web.AppKey[set] = web.AppKey("sockets", set)
LIMITS: web.AppKey[StudioLimits] = web.AppKey("limits", StudioLimits)
UPLOADS: web.AppKey[asyncio.Semaphore] = web.AppKey("uploads", asyncio.Semaphore)
#: The threads that decode uploaded pictures, one per upload slot (the loop's default executor has
#: many more, which its other work may need meanwhile).
DECODERS: web.AppKey[ThreadPoolExecutor] = web.AppKey("decoders", ThreadPoolExecutor)
#: Seconds the studio waits at its end for requests in flight (a page's socket is closed).
SHUTDOWN_S: float = 2.0
#: Seconds between two returns of the server's freed heap to the system
#: (:func:`~grassd.daemon.core.runtime.freed_memory.release_freed_memory`): what a burst of
#: requests or a decoded upload left resident is given back within this time.
RELEASE_EVERY_S: float = 2.0


def static_dir() -> Path:
    """The page and its vendored assets (package data)."""
    return Path(str(resources.files("grassd.daemon.studio").joinpath("static")))


def _error(status: int, message: str) -> web.Response:
    return web.json_response({"error": message}, status=status)


def _refuse(request: web.Request, status: int, message: str,
            headers: dict[str, str] | None = None, *, linger: bool = False) -> web.Response:
    """A JSON error after which the connection is closed. Without ``linger`` the rest of the
    request's body is not read (a stranger's, one too slow); with it aiohttp reads and
    discards it for up to 10 s first, so that a client still sending its body gets the
    answer rather than a reset (an upload too large, or while the slots are taken)."""
    protocol = request.protocol
    if not linger and isinstance(protocol, StudioConnection):
        protocol.refuse_body()
    response = web.json_response({"error": message}, status=status, headers=headers)
    response.force_close()
    return response


def _raw_response(status: int, reason: str, message: str) -> bytes:
    """A whole HTTP/1.1 JSON error response that closes the connection, as bytes (for a
    connection that never got as far as a request aiohttp could answer)."""
    body = json.dumps({"error": message}).encode()
    return (f"HTTP/1.1 {status} {reason}\r\nContent-Type: application/json; charset=utf-8\r\n"
            f"Content-Length: {len(body)}\r\nConnection: close\r\n\r\n").encode() + body


@web.middleware
async def _guard(request: web.Request, handler):
    """The origin and token checks and JSON errors for every failure. A request a browser sends
    from another site's page (its Origin is not this server) is refused: without it, any page
    the user visits could drive a studio on 127.0.0.1 and upload into it."""
    protocol = request.protocol
    if isinstance(protocol, StudioConnection):
        protocol.request_started()
    try:
        return await _checked(request, handler)
    finally:
        if isinstance(protocol, StudioConnection):
            protocol.request_ended()


async def _checked(request: web.Request, handler):
    origin = request.headers.get("Origin")
    try:
        origin_host = None if origin is None else urlsplit(origin).netloc
        host_name = urlsplit(f"//{request.host}").hostname
    except ValueError:  # e.g. "[" or "[::1" as a Host
        return _refuse(request, 400, "the request's Host or Origin header is not a host name")
    if origin is not None and origin_host != request.host:
        return _refuse(request, 403, f"requests from {origin[:80]} are refused: open the "
                                     f"studio's own page")
    token = request.app[TOKEN]
    if token is None and host_name not in LOCAL_NAMES:
        return _refuse(request, 403, f"this studio answers as 127.0.0.1 or localhost only, "
                                     f"not as {request.host[:80]}: open the URL it printed at "
                                     f"start")
    if token is not None:
        given = (request.query.get("token") or request.headers.get("X-Grassd-Token")
                 or request.cookies.get(COOKIE) or "")
        if not hmac.compare_digest(given.encode(), token.encode()):
            return _refuse(request, 401, "this studio needs its token: open the URL it printed "
                                         "at start (…/?token=…)")
    try:
        response = await handler(request)
    except web.HTTPRequestEntityTooLarge as exc:
        return _refuse(request, 413, f"the upload is too large ({exc.text})", linger=True)
    except BodyTimeout as exc:
        return _refuse(request, 408, str(exc))
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


def parse_json(text: str | bytes, what: str = "the body") -> JsonValue:
    """``text`` decoded as JSON; StudioInputError saying why where it is not (too deeply
    nested, or an integer of more digits than Python converts, included)."""
    try:
        return json.loads(text)
    except RecursionError:
        raise StudioInputError(f"{what} is nested too deeply to be a request") from None
    except (ValueError, UnicodeDecodeError) as exc:  # JSONDecodeError and integer limits
        raise StudioInputError(f"{what} must be JSON ({exc})") from None


async def _json_body(request: web.Request) -> JsonValue:
    return parse_json(await _read_capped(request, MAX_JSON_BYTES, "a JSON request"))


def _check_cost(studio: Studio, limits: StudioLimits, cond: Condition,
                what: str = "this request") -> None:
    """Refuse (:class:`~grassd.daemon.studio.cost.JobTooCostly`) a condition whose
    characteristic would cost more than the studio's cap."""
    check_cost(cond, studio.splay_deg(cond), limits.job_cost, what)


async def _characteristic(request: web.Request) -> web.Response:
    studio = request.app[STUDIO]
    try:
        data = await _json_body(request)
        cond = studio.parse(data)
        target = data.get("target_stderr") if isinstance(data, dict) else None
        kw: CharacteristicArgs
        if target is None:
            kw = {"target_stderr": None, "samples": studio.cfg.simulation.samples,
                  "replicates": studio.cfg.calibration.replicates}
        else:
            _check_cost(studio, request.app[LIMITS], cond)
            kw = {"target_stderr": cond.target_stderr}
    except StudioInputError as exc:
        return _error(400, str(exc))
    t0 = time.perf_counter()
    simulator, owner = request.app[SIMULATOR], next(_OWNERS)
    try:
        curve = await simulator.submit(owner, CurveJob(cond, kw))
    except asyncio.CancelledError:  # the client went away: its job stops too
        simulator.cancel(owner)
        raise
    except StudioInputError as exc:
        return _error(400, str(exc))
    except RuntimeError as exc:  # the renderer failed: said, the studio goes on
        return _error(500, str(exc))
    assert curve is not None  # a characteristic's job answers its curve
    msg = curve_message(curve, kw["target_stderr"])
    out: CharacteristicAnswer = {
        "lengths_mm": msg["lengths_mm"], "ogcd": msg["ogcd"], "ogcd_stderr": msg["ogcd_stderr"],
        "replicates": msg["replicates"], "seconds": round(time.perf_counter() - t0, 4)}
    return web.json_response(out)


class BodyTimeout(DaemonError):
    """A request's body did not arrive within the studio's deadlines (a 408, the connection
    closed)."""


async def _chunks(request: web.Request, limit: int, what: str):
    """The request's body in pieces, at most ``limit`` bytes in all (413 beyond), each piece
    within ``body_idle_s`` of the last and all of it within ``body_s`` (:class:`BodyTimeout`)."""
    limits = request.app[LIMITS]
    too_large = dict(text=f"{what}: at most {limit // 2**20} MiB")
    if request.content_length is not None and request.content_length > limit:
        raise web.HTTPRequestEntityTooLarge(max_size=limit, actual_size=request.content_length,
                                            **too_large)
    loop = asyncio.get_running_loop()
    end = loop.time() + limits.body_s
    size = 0
    while True:
        wait = min(limits.body_idle_s, end - loop.time())
        try:
            async with asyncio.timeout(max(wait, 0.0)):
                chunk = await request.content.readany()
        except TimeoutError:
            whole = end - loop.time() <= 0
            raise BodyTimeout(
                f"{what} did not arrive in time: "
                + (f"all of it must come within {limits.body_s:g} s" if whole else
                   f"nothing came for {limits.body_idle_s:g} s")
                + f" ({size} bytes came); send it again on a faster link") from None
        if not chunk:  # the end of the body
            return
        size += len(chunk)
        if size > limit:
            raise web.HTTPRequestEntityTooLarge(max_size=limit, actual_size=size, **too_large)
        yield chunk


async def _read_capped(request: web.Request, limit: int, what: str) -> bytes:
    """The whole body (:func:`_chunks`'s caps and deadlines)."""
    return b"".join([chunk async for chunk in _chunks(request, limit, what)])


def _busy(request: web.Request) -> web.Response:
    slots = request.app[LIMITS].upload_slots
    return _refuse(request, 503, f"the studio is reading another upload (at most {slots} at a "
                                 f"time): send this one again when that one is done",
                   headers={"Retry-After": "2"}, linger=True)


async def _upload(request: web.Request, read: Callable[[], Awaitable[_Body]],
                  decode: Callable[[_Body], Awaitable[_Decoded]]) -> _Decoded:
    """``decode(await read())`` holding one of the studio's upload slots: the body is read
    only once a slot is free (else :class:`_UploadsBusy`, answered 503 from the headers, the
    body then discarded as it comes, never kept), and the slot is held until the decoding
    ends, even when the client goes away meanwhile (the decoder's thread goes on)."""
    slots = request.app[UPLOADS]
    if slots.locked():
        raise _UploadsBusy
    await slots.acquire()
    handed = False
    try:
        data = await read()
        work = asyncio.ensure_future(decode(data))
        work.add_done_callback(lambda _f: slots.release())
        handed = True
        return await asyncio.shield(work)
    finally:
        if not handed:
            slots.release()


class _UploadsBusy(Exception):  # noqa: N818 (the condition, answered as a 503)
    """Every upload slot is taken."""


async def _hdri(request: web.Request) -> web.Response:
    studio, simulator = request.app[STUDIO], request.app[SIMULATOR]
    name = request.query.get("name", "")

    async def read() -> Path:  # to its file as it comes: never the whole body in memory
        path = studio.lights.upload_path(name)
        try:
            with path.open("wb") as f:
                async for chunk in _chunks(request, MAX_HDRI_BYTES, "an HDRI"):
                    f.write(chunk)
        except BaseException:  # cut short, too large, too slow
            path.unlink(missing_ok=True)
            raise
        return path

    async def add(file: Path) -> LightSource:  # both lists get it, even if the client goes
        src = studio.lights.new_upload(name, file)  # away; only the simulator decodes it
        try:
            await simulator.check_light(src, Path(name).name)
        except BaseException:
            file.unlink(missing_ok=True)
            raise
        for old in studio.lights.keep_upload(src):  # the oldest beyond the caps leave both
            simulator.forget_light(old)
        return src

    try:
        src = await _upload(request, read, add)
    except _UploadsBusy:
        return _busy(request)
    except StudioInputError as exc:
        return _error(400, str(exc))
    except RuntimeError as exc:  # the simulator ended while it checked: said, it restarts
        return _error(500, str(exc))
    return web.json_response({"light": src.describe(), "lights": studio.lights.describe()})


async def _picture(request: web.Request) -> web.Response:
    studio = request.app[STUDIO]
    if request.content_type.startswith("multipart/"):
        return _refuse(request, 400, "send the picture's own bytes as the request's body, not "
                                     "a form (curl --data-binary @picture.png)", linger=True)
    loop = asyncio.get_running_loop()

    async def decode(data: bytes) -> PictureUpload:  # a large picture takes a while: not on
        return await loop.run_in_executor(request.app[DECODERS],  # the event loop
                                          studio.add_picture, data)

    try:
        return web.json_response(await _upload(
            request, lambda: _read_capped(request, MAX_IMAGE_BYTES, "a picture"), decode))
    except _UploadsBusy:
        return _busy(request)
    except StudioInputError as exc:
        return _error(400, str(exc))


#: What a page sends over the WebSocket (said to one that sends something else).
_WS_FORM = 'send text messages {"type": "inputs", "id": n, "condition": {...}}'
#: The close code of a page's socket dropped for not reading (RFC 6455: policy violation).
DROPPED_CODE: int = 1008


class Outbox:
    """The messages waiting to be sent to one page, at most ``most`` of them and ``most_bytes``
    of JSON together; :meth:`put` says False (and the outbox takes nothing more) once a
    message would go beyond either."""

    def __init__(self, most: int, most_bytes: int) -> None:
        self._items: deque[str] = deque()
        self._bytes = 0
        self._most, self._most_bytes = most, most_bytes
        self._ready = asyncio.Event()
        self.full = False

    def __len__(self) -> int:
        return len(self._items)

    def put(self, msg: PageMessage) -> bool:
        """Queue ``msg``; False when the outbox is (or now becomes) full."""
        if self.full:
            return False
        text = json.dumps(msg)
        if len(self._items) >= self._most or self._bytes + len(text) > self._most_bytes:
            self.full = True
            self._items.clear()  # what it held is never sent: the page is dropped
            self._bytes = 0
            self._ready.set()
            return False
        self._items.append(text)
        self._bytes += len(text)
        self._ready.set()
        return True

    async def get(self) -> str | None:
        """The next message to send; None once the outbox is full."""
        while not self._items:
            if self.full:
                return None
            self._ready.clear()
            await self._ready.wait()
        text = self._items.popleft()
        self._bytes -= len(text)
        return text


async def _drop(ws: web.WebSocketResponse, request: web.Request, why: str) -> None:
    """Close a page's socket (1008, ``why``); its connection is cut after ``body_idle_s``
    if the page does not take the close frame (it does not read)."""
    transport = request.transport
    grace = request.app[LIMITS].body_idle_s
    log.warning("a page's socket was closed: %s", why)
    if transport is not None:
        asyncio.get_running_loop().call_later(grace, transport.abort)
    with contextlib.suppress(Exception):
        async with asyncio.timeout(grace):
            await ws.close(code=DROPPED_CODE, message=why.encode()[:120], drain=False)


def _pinned(studio: Studio, limits: StudioLimits, given: JsonValue, tag: int,
            send: Callable[[PageMessage], None]) -> Condition | None:
    """The condition ``given`` to show as B beside the page's input ``tag``: None where there
    is none, or where it cannot be used (said as B's; A goes on)."""
    if given is None:
        return None
    try:
        pinned = studio.parse(given)
        _check_cost(studio, limits, pinned, "the condition pinned as B")
    except _BAD_INPUT as exc:
        send({"type": "pinned", "id": tag, "error": str(exc), "final": True})
        return None
    return pinned


async def _socket(request: web.Request) -> web.WebSocketResponse:
    """One page: its latest inputs run on the simulator, the views stream back."""
    studio, simulator = request.app[STUDIO], request.app[SIMULATOR]
    limits = request.app[LIMITS]
    ws = web.WebSocketResponse(heartbeat=30.0, max_msg_size=MAX_JSON_BYTES)
    await ws.prepare(request)
    request.app[SOCKETS].add(ws)
    owner = next(_OWNERS)
    outbox = Outbox(limits.outbox_messages, limits.outbox_bytes)
    dropping: list[asyncio.Task] = []
    why = (f"this page does not read its messages ({limits.outbox_messages} or "
           f"{limits.outbox_mib} MiB waiting): reload it")

    def send(msg: PageMessage) -> None:
        if not outbox.put(msg) and not dropping:
            simulator.cancel(owner)
            dropping.append(asyncio.ensure_future(_drop(ws, request, why)))

    async def sender() -> None:
        while True:
            text = await outbox.get()
            if text is None or ws.closed:
                return
            await ws.send_str(text)

    def finished(fut: asyncio.Future, tag: int) -> None:
        exc = None if fut.cancelled() else fut.exception()
        if isinstance(exc, StudioInputError) or (exc is not None
                                                 and not isinstance(exc, Superseded)):
            send({"type": "error", "id": tag, "message": str(exc)})

    task = asyncio.create_task(sender())
    try:
        async for m in ws:
            if dropping:
                break
            if m.type == WSMsgType.BINARY:
                send({"type": "error", "id": 0, "message": _WS_FORM})
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
                _check_cost(studio, limits, cond, "this input")
                picture = studio.picture(cond.image)
            except _BAD_INPUT as exc:
                simulator.cancel(owner)
                send({"type": "error", "id": tag, "message": str(exc)})
                continue
            pinned = _pinned(studio, limits, data.get("pinned"), tag, send)

            def emit(msg: PageMessage, tag: int = tag) -> None:
                msg["id"] = tag
                send(msg)

            fut = simulator.submit(owner, ViewsJob(cond, picture, pinned), emit)
            fut.add_done_callback(lambda f, tag=tag: finished(f, tag))
    finally:
        request.app[SOCKETS].discard(ws)
        simulator.cancel(owner)
        task.cancel()
        if dropping:
            await asyncio.shield(dropping[0])
    return ws


async def _close_sockets(app: web.Application) -> None:
    """At the studio's end: close every page's socket (it would hold the end up otherwise)."""
    for ws in list(app[SOCKETS]):
        with contextlib.suppress(Exception):
            async with asyncio.timeout(SHUTDOWN_S):
                await ws.close(code=1001, message=b"the studio is stopping", drain=False)


async def _stop_decoders(app: web.Application) -> None:
    app[DECODERS].shutdown(wait=False, cancel_futures=True)


def make_app(studio: Studio, simulator: SimulatorProcess, token: str | None = None,
             limits: StudioLimits = DEFAULT_LIMITS) -> web.Application:
    """The studio's aiohttp application (the page, the API, the WebSocket)."""
    app = web.Application(middlewares=[_guard], client_max_size=MAX_HDRI_BYTES + 2**20)
    app[STUDIO] = studio
    app[SIMULATOR] = simulator
    app[TOKEN] = token
    app[SOCKETS] = set()
    app[LIMITS] = limits
    app[UPLOADS] = asyncio.Semaphore(limits.upload_slots)
    app[DECODERS] = ThreadPoolExecutor(limits.upload_slots,
                                       thread_name_prefix="grassd-studio-upload")
    app.on_shutdown.append(_close_sockets)
    app.on_cleanup.append(_stop_decoders)
    app.router.add_get("/", _index)
    app.router.add_get("/api/state", _state)
    app.router.add_post("/api/characteristic", _characteristic)
    app.router.add_post("/api/hdri", _hdri)
    app.router.add_post("/api/picture", _picture)
    app.router.add_get("/ws", _socket)
    app.router.add_static("/static/", static_dir(), append_version=False)
    return app


class Connections:
    """The open connections of one studio, oldest first, at most ``most``: at the cap, a new
    connection closes the oldest that is not being served (waiting for its headers, or idle
    between requests); when every one is being served, the new one is refused."""

    def __init__(self, most: int) -> None:
        self.most = most
        self._open: OrderedDict[StudioConnection, None] = OrderedDict()

    def __len__(self) -> int:
        return len(self._open)

    def admit(self, conn: StudioConnection) -> bool:
        """Whether ``conn`` may stay open (room made for it when needed)."""
        if len(self._open) >= self.most:
            idle = next((c for c in self._open if not c.busy), None)
            if idle is None:
                return False
            del self._open[idle]
            idle.evict(f"the studio has {self.most} connections open and this one was not "
                       f"being served: connect again")
        self._open[conn] = None
        return True

    def left(self, conn: StudioConnection) -> None:
        """``conn`` has closed."""
        self._open.pop(conn, None)


class HandlerOptions(TypedDict, total=False):
    """What a :class:`StudioConnection` hands on to aiohttp's ``RequestHandler`` (an
    ``access_log`` of None: none)."""

    access_log: logging.Logger | None
    keepalive_timeout: float
    max_headers: int


class StudioConnection(RequestHandler):
    """aiohttp's handler of one connection, kept within the studio's limits: its request line
    and headers within ``header_s`` of its opening or of its previous request's end (else a
    408 where some of a request came, and closed), counted against the connection cap
    (:class:`Connections`), and closed without reading the rest of a refused request's body
    (:meth:`refuse_body`)."""

    def __init__(self, manager: web.Server, connections: Connections, limits: StudioLimits,
                 *, loop: asyncio.AbstractEventLoop, **kwargs: Unpack[HandlerOptions]) -> None:
        super().__init__(manager, loop=loop, **kwargs)  # type: ignore[arg-type]  # takes a None log
        self._connections = connections
        self._limits = limits
        self.busy = 0  # requests being served (the middleware counts them)
        self._served = 0  # requests answered
        self._received = 0  # bytes received, and at the last arming of the header deadline
        self._armed_at = 0
        self._deadline: asyncio.TimerHandle | None = None

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        """Count the connection (refused at the cap) and start its header deadline."""
        super().connection_made(transport)
        if not self._connections.admit(self):
            self._answer(503, "Service Unavailable",
                         f"the studio has {self._connections.most} connections open, each "
                         f"being served: try again in a moment")
            return
        self._arm()

    def connection_lost(self, exc: BaseException | None) -> None:
        """Uncount the connection."""
        self._connections.left(self)
        if self._deadline is not None:
            self._deadline.cancel()
        super().connection_lost(exc)

    def data_received(self, data: bytes) -> None:
        """Count what came (a request begun is answered 408 at its deadline). A request the
        parser refuses (too many header lines, too long a line) is queued with its exception,
        whose traceback holds aiohttp's frame and so the chunk read (up to 256 KiB) in a
        reference cycle that only the cyclic collector frees: the traceback is let go here,
        or hundreds of such requests in a row hold their chunks until it runs."""
        self._received += len(data)
        super().data_received(data)
        for message, _payload in self._messages:
            if isinstance(message, _ErrInfo):
                message.exc.__traceback__ = None

    def request_started(self) -> None:
        """A request's headers are in: it is being served (no header deadline)."""
        self.busy += 1
        if self._deadline is not None:
            self._deadline.cancel()
            self._deadline = None

    def request_ended(self) -> None:
        """A request has been answered: the next one's headers have ``header_s``."""
        self.busy -= 1
        self._served += 1
        if not self.busy:
            self._arm()

    def refuse_body(self) -> None:
        """Close the connection after the answer without reading the rest of the body."""
        self._lingering_time = 0.0

    def evict(self, why: str) -> None:
        """Close this connection, which is not being served, to make room (a 503 unless it is
        idle after an answer)."""
        if self._begun():
            self._answer(503, "Service Unavailable", why)
        else:
            self.force_close()

    def _begun(self) -> bool:
        """Whether a request is owed an answer: some of one came since the last answer, or the
        connection has had none yet."""
        return self._received > self._armed_at or not self._served

    def _arm(self) -> None:
        if self._deadline is not None:
            self._deadline.cancel()
        self._armed_at = self._received
        self._deadline = self._loop.call_later(self._limits.header_s, self._late)

    def _late(self) -> None:
        self._deadline = None
        if self.busy:
            return
        if self._begun():  # a request begun, its headers unfinished
            self._answer(408, "Request Timeout",
                         f"the request's headers did not come within "
                         f"{self._limits.header_s:g} s of the connection's opening (or of the "
                         f"previous answer): send a whole request at once")
        else:  # idle between requests
            self.force_close()

    def _answer(self, status: int, reason: str, message: str) -> None:
        """Answer ``status`` outside aiohttp's request cycle and close."""
        transport = self.transport
        if transport is not None and not transport.is_closing():
            with contextlib.suppress(Exception):
                transport.write(_raw_response(status, reason, message))
        self.force_close()


class StudioSite(web.BaseSite):
    """A TCP site whose connections are :class:`StudioConnection`\\ s (aiohttp's own
    ``TCPSite`` makes plain handlers, which have no header deadline or cap)."""

    def __init__(self, runner: web.AppRunner, host: str, port: int,
                 limits: StudioLimits, **handler_kwargs: Unpack[HandlerOptions]) -> None:
        super().__init__(runner)
        self._host, self._port = host, port
        self._limits = limits
        self._handler_kwargs = handler_kwargs
        self.connections = Connections(limits.connections)

    @property
    def name(self) -> str:
        """The site's URL (as aiohttp names its sites)."""
        return f"http://{self._host}:{self._port}"

    async def start(self) -> None:
        """Listen."""
        await super().start()
        loop = asyncio.get_running_loop()
        server = self._runner.server
        assert server is not None

        def connection() -> StudioConnection:
            return StudioConnection(server, self.connections, self._limits, loop=loop,
                                    **self._handler_kwargs)

        self._server = await loop.create_server(connection, self._host, self._port,
                                                reuse_address=True)

    @property
    def bound(self) -> tuple[str, int]:
        """The (host, port) it listens on (the port the OS chose for port 0)."""
        assert self._server is not None
        return self._server.sockets[0].getsockname()[:2]


async def _release_freed_memory() -> None:
    """Every :data:`RELEASE_EVERY_S`, give the server's freed heap back to the system."""
    while True:
        await asyncio.sleep(RELEASE_EVERY_S)
        release_freed_memory()


async def serve(args: StudioArgs, host: str, port: int, token: str | None,
                ready: asyncio.Future | None = None) -> None:
    """Serve the studio ``args`` describe until cancelled or sent SIGTERM (uploads removed,
    the simulator stopped either way); ``ready`` gets the bound (host, port). The simulations
    run in a child process (:mod:`.process`); the server's caps are ``args.limits``."""
    studio = args.build()
    limits = args.limits

    def warmed(seconds: float) -> None:
        studio.ready = True
        log.info("studio warmed up in %.1f s", seconds)

    simulator = SimulatorProcess(args, warmed)
    # handler_cancellation: a request whose client went away is cancelled, and so its job;
    # aiohttp's own keep-alive close is a backstop behind the connections' header deadline
    runner = web.AppRunner(make_app(studio, simulator, token, limits), access_log=None,
                           handler_cancellation=True, shutdown_timeout=SHUTDOWN_S)
    stop = asyncio.Event()  # SIGTERM (systemd, kill) ends it as Ctrl-C does: cleaned up
    loop = asyncio.get_running_loop()
    with contextlib.suppress(NotImplementedError, RuntimeError):  # no signals off the main
        loop.add_signal_handler(signal.SIGTERM, stop.set)  # thread
    try:
        await runner.setup()
        site = StudioSite(runner, host, port, limits, access_log=None,
                          keepalive_timeout=2 * limits.header_s,
                          max_headers=limits.header_fields)
        await site.start()
        if ready is not None:
            ready.set_result(site.bound)
        releasing = asyncio.create_task(_release_freed_memory())
        await stop.wait()
        releasing.cancel()
    finally:
        with contextlib.suppress(NotImplementedError, RuntimeError):
            loop.remove_signal_handler(signal.SIGTERM)
        try:
            await runner.cleanup()
        finally:
            simulator.stop()
            studio.lights.cleanup()


__all__ = ["LOCAL_HOST", "Connections", "Outbox", "StudioConnection", "StudioSite", "make_app",
           "serve", "static_dir"]
