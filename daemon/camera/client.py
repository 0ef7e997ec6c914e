"""A client for the Open Spherical Camera API (level 2, as RICOH THETA Web API v2.1 speaks it).

Endpoints used (https://developers.google.com/streetview/open-spherical-camera/guides/osc):

* ``GET /osc/info``: manufacturer, model, serialNumber, firmwareVersion, apiLevel;
* ``POST /osc/state``: fingerprint and state (battery, ``_captureStatus`` on THETA);
* ``POST /osc/commands/execute`` ``{"name": ..., "parameters": {...}}``: a command object with
  ``state`` "done" (``results``), "inProgress" (``id``, poll it) or "error" (``error.code``,
  ``error.message``);
* ``POST /osc/commands/status`` ``{"id": ...}``: the same command object, polled until done;
* the shot itself by the absolute ``fileUrl`` of ``camera.takePicture``'s results (and
  ``_dngFileUrl`` for RAW+ on a THETA Z1).

Commands: ``camera.setOptions`` / ``camera.getOptions`` (``captureMode``, ``exposureProgram``,
``iso``, ``shutterSpeed``, ``whiteBalance``, ``fileFormat``), ``camera.takePicture`` and THETA's
``camera._getMetadata`` (the shot's EXIF as JSON; optional, other cameras lack it). Before a
bracket the camera is put in still-image capture (``captureMode`` "image",
:meth:`OscClient.ensure_image_mode`): a THETA left in video or interval mode refuses
``camera.takePicture``.

A command the camera refuses (an OSC error object, whatever HTTP status it came with: 400 or
403 on a THETA, 200 on some cameras) is a
:class:`~grassd.daemon.core.errors.CameraCommandRefused` that quotes the camera's error code and
message.

A THETA in Wi-Fi client mode (on the site's network) requires HTTP digest authentication:
user name = the camera's ID printed on it (``THETAYN`` + the serial digits on a Z1,
``THETAYL...`` on a V), password = the serial digits unless changed; in access-point mode no
authentication is asked. Digest auth is urllib's ``HTTPDigestAuthHandler``.

Every failure is a typed :class:`~grassd.daemon.core.errors.CameraError` naming the URL.
Network traffic goes only to the configured URL: a ``fileUrl`` naming another host (a THETA
in client mode names its own IP, while the configuration may name it by host name) is fetched
from the configured one, and one that is not http(s) (``file:///etc/...``) is refused.

What the camera (or anyone on its Wi-Fi) sends is not trusted:

* no redirect is followed (an OSC camera never redirects; following one would send the request,
  and the digest credentials' next attempt, to whatever host it names): a 3xx answer is a
  :class:`~grassd.daemon.core.errors.CameraHttpError` saying where it pointed;
* every answer is read in chunks up to a byte cap (``max_json_bytes`` for the JSON of
  commands, ``max_download_bytes`` for a shot, which is streamed to disk, never held in
  memory): one byte more is a typed error, and a Content-Length above the cap is refused
  before any of the body is read;
* every request has a wall-clock deadline (``request_deadline_s``, ``download_deadline_s``)
  from connecting to the last byte, on top of ``timeout_s`` per read: when it passes, a
  watchdog shuts the request's sockets down, so an answer trickling one byte a second ends
  at the deadline however many reads it takes.
"""

from __future__ import annotations

import contextlib
import functools
import http.client
import json
import logging
import os
import socket
import threading
import time
import urllib.error
import urllib.parse
import urllib.request
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any, NoReturn, Unpack, cast

from grassd.daemon.camera.config import CaptureConfig
from grassd.daemon.camera.messages import (
    ExifValue,
    OscCommand,
    OscErrorBody,
    OscOptions,
    OscParameters,
    OscRequest,
    OscResults,
    OscState,
)
from grassd.daemon.core.errors import (
    CameraCommandRefused,
    CameraCommandTimeout,
    CameraDownloadError,
    CameraError,
    CameraHttpError,
    CameraProtocolError,
    CameraUnreachable,
    CaptureModeRefused,
)

log = logging.getLogger(__name__)

#: Seconds an HTTP request may take before the camera counts as unreachable ([capture]'s).
DEFAULT_TIMEOUT_S = CaptureConfig.timeout_s
#: Seconds a command (takePicture: exposure + stitching, up to a minute on a THETA Z1 at long
#: exposures) may stay inProgress ([capture]'s).
DEFAULT_COMMAND_TIMEOUT_S = CaptureConfig.command_timeout_s
#: Seconds between two /osc/commands/status polls.
DEFAULT_POLL_S = 0.25
#: Seconds a JSON request may take in all, connecting to last byte ([capture]'s).
DEFAULT_REQUEST_DEADLINE_S = CaptureConfig.request_deadline_s
#: Seconds a shot's download may take in all ([capture]'s).
DEFAULT_DOWNLOAD_DEADLINE_S = CaptureConfig.download_deadline_s
#: Bytes a JSON answer may hold ([capture]'s).
DEFAULT_MAX_JSON_BYTES = CaptureConfig.max_json_bytes
#: Bytes a downloaded shot may hold ([capture]'s).
DEFAULT_MAX_DOWNLOAD_BYTES = CaptureConfig.max_download_bytes
#: Slowest download (bytes/s) over a window (s) before it is cut ([capture]'s).
DEFAULT_MIN_DOWNLOAD_RATE = CaptureConfig.min_download_rate
DEFAULT_MIN_DOWNLOAD_WINDOW_S = CaptureConfig.min_download_window_s
#: Bytes read from a socket at a time.
CHUNK_BYTES = 64 * 1024
#: Bytes of an HTTP error's body quoted in the error message.
_ERROR_BODY_BYTES = 300
#: Bytes of an HTTP error's body read to find an OSC error object in it (one is under 1 kB).
_OSC_ERROR_BYTES = 8192
#: The ``captureMode`` of still-image capture (OSC level 2; THETA Web API v2.1).
IMAGE_MODE = "image"


@dataclass(frozen=True)
class CameraInfo:
    """``/osc/info`` of a camera."""

    manufacturer: str
    model: str
    serial: str
    firmware: str
    api_levels: tuple[int, ...]

    @property
    def key(self) -> str:
        """A file-name-safe identity of this camera (model, serial, firmware): one camera
        response is kept per key."""
        raw = f"{self.manufacturer}-{self.model}-{self.serial}-{self.firmware}"
        return "".join(ch if ch.isalnum() or ch in "._-" else "_" for ch in raw)


def _mib(n: int) -> str:
    return f"{n / (1 << 20):.3g} MiB"


def _origin(url: str) -> tuple[str, str, int | None]:
    """(scheme, host, port) of ``url``, the port filled in for http and https."""
    parts = urllib.parse.urlsplit(url)
    try:
        port = parts.port
    except ValueError:
        port = None
    return (parts.scheme.lower(), (parts.hostname or "").lower(),
            port or {"http": 80, "https": 443}.get(parts.scheme.lower()))


class _Deadline:
    """The wall-clock limit of one request. Every socket opened for the request (the first, a
    digest-auth retry's) is registered; when ``seconds`` have passed, a timer thread shuts them
    down, so a blocked read returns at once (end of stream) whatever the per-read timeout.
    ``expired`` then tells the reader why its stream ended."""

    def __init__(self, seconds: float) -> None:
        self.seconds = seconds
        self.end = time.monotonic() + seconds
        self.expired = False
        self._socks: list[socket.socket] = []
        self._lock = threading.Lock()
        self._timer = threading.Timer(seconds, self._expire)
        self._timer.daemon = True

    def __enter__(self) -> _Deadline:
        self._timer.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._timer.cancel()

    @property
    def over(self) -> bool:
        """The deadline has passed (or will within 50 ms: a read timeout cut to the time left
        fires just before the watchdog)."""
        return self.expired or self.remaining() < 0.05

    def remaining(self) -> float:
        """Seconds left (0 when passed)."""
        return max(self.end - time.monotonic(), 0.0)

    def clamp(self, timeout: float | None) -> float:
        """``timeout`` (s; None: none) cut to the time left, at least 1 ms."""
        left = max(self.remaining(), 0.001)
        return left if timeout is None else min(timeout, left)

    def add(self, sock: socket.socket) -> None:
        """Shut ``sock`` down when the deadline passes (at once if it has)."""
        with self._lock:
            self._socks.append(sock)
            if not self.expired:
                return
        self._shut(sock)

    def _expire(self) -> None:
        with self._lock:
            self.expired = True
            socks = list(self._socks)
        for sock in socks:
            self._shut(sock)

    @staticmethod
    def _shut(sock: socket.socket) -> None:
        # shutdown, not close: the fd stays the reader's (closing it under a blocked read could
        # let a new socket reuse its number); a closed socket raises OSError here, ignored
        with contextlib.suppress(OSError):
            sock.shutdown(socket.SHUT_RDWR)


class _DeadlineConnection:
    """Mixin for http.client connections: the connect timeout is cut to the time left of the
    current request's deadline (TLS's handshake, too, is bounded by it as a whole), and the
    connected socket is registered with that deadline."""

    def __init__(self, *args: Any, deadline_of: Callable[[], _Deadline | None],
                 **kw: Any) -> None:
        self._deadline_of = deadline_of
        super().__init__(*args, **kw)  # type: ignore[call-arg]

    def connect(self) -> None:
        deadline: _Deadline | None = self._deadline_of()
        if deadline is not None:
            self.timeout = deadline.clamp(self.timeout)  # type: ignore[attr-defined]
        super().connect()  # type: ignore[misc]
        if deadline is not None:
            deadline.add(self.sock)  # type: ignore[attr-defined]


class _HttpConnection(_DeadlineConnection, http.client.HTTPConnection):
    pass


class _HttpsConnection(_DeadlineConnection, http.client.HTTPSConnection):
    pass


class _DeadlineHandler(urllib.request.HTTPHandler, urllib.request.HTTPSHandler):
    """urllib's http and https handlers, opening :class:`_DeadlineConnection` connections."""

    def __init__(self, deadline_of: Callable[[], _Deadline | None]) -> None:
        urllib.request.HTTPSHandler.__init__(self)
        self._deadline_of = deadline_of

    def http_open(self, req: urllib.request.Request) -> http.client.HTTPResponse:
        return self.do_open(functools.partial(_HttpConnection, deadline_of=self._deadline_of),
                            req)

    def https_open(self, req: urllib.request.Request) -> http.client.HTTPResponse:
        return self.do_open(functools.partial(_HttpsConnection, deadline_of=self._deadline_of),
                            req, context=self._context)


class _NoRedirects(urllib.request.HTTPRedirectHandler):
    """Refuses every redirect with a CameraHttpError saying where it pointed (before reading its
    body), instead of urllib's following it to any host."""

    def redirect_request(self, req: urllib.request.Request, fp: IO[bytes], code: int,
                         msg: str, headers: http.client.HTTPMessage,
                         newurl: str) -> NoReturn:
        fp.close()
        elsewhere = _origin(newurl) != _origin(req.full_url)
        where = ("another host" if _origin(newurl)[1] != _origin(req.full_url)[1]
                 else "another scheme or port" if elsewhere else "another path")
        raise CameraHttpError(
            f"camera {req.full_url} answered HTTP {code} {msg}, a redirect to {where} "
            f"({newurl[:200]!r}); grassd follows no redirects (an OSC camera never sends one, "
            "so something else answers at this address): check [capture] camera and who is on "
            "the camera's network", code)


class OscClient:
    """An OSC camera at ``url`` (e.g. ``http://192.168.1.1`` in access-point mode).

    ``username``/``password``: digest authentication (THETA in Wi-Fi client mode);
    ``timeout_s``: per HTTP read (connect, each wait for data); ``command_timeout_s``: per
    command until done; ``request_deadline_s`` / ``download_deadline_s``: per JSON request /
    per download, start to last byte, however slowly the bytes come (s); ``max_json_bytes`` /
    ``max_download_bytes``: the largest answer / file accepted (bytes).
    """

    def __init__(self, url: str, *, username: str | None = None, password: str | None = None,
                 timeout_s: float = DEFAULT_TIMEOUT_S,
                 command_timeout_s: float = DEFAULT_COMMAND_TIMEOUT_S,
                 poll_s: float = DEFAULT_POLL_S,
                 request_deadline_s: float = DEFAULT_REQUEST_DEADLINE_S,
                 download_deadline_s: float = DEFAULT_DOWNLOAD_DEADLINE_S,
                 max_json_bytes: int = DEFAULT_MAX_JSON_BYTES,
                 max_download_bytes: int = DEFAULT_MAX_DOWNLOAD_BYTES,
                 min_download_rate: int = DEFAULT_MIN_DOWNLOAD_RATE,
                 min_download_window_s: float = DEFAULT_MIN_DOWNLOAD_WINDOW_S) -> None:
        parsed = urllib.parse.urlparse(url)
        if parsed.scheme not in ("http", "https") or not parsed.netloc:
            raise CameraUnreachable(f"camera URL {url!r} is not an http:// URL "
                                    "(e.g. http://192.168.1.1)")
        self.url = url.rstrip("/")
        self.timeout_s = timeout_s
        self.command_timeout_s = command_timeout_s
        self.poll_s = poll_s
        self.request_deadline_s = request_deadline_s
        self.download_deadline_s = download_deadline_s
        self.max_json_bytes = max_json_bytes
        self.max_download_bytes = max_download_bytes
        self.min_download_rate, self.min_download_window_s = (min_download_rate,
                                                              min_download_window_s)
        self._local = threading.local()  # .deadline: the current request's, per thread

        def deadline_of() -> _Deadline | None:
            return getattr(self._local, "deadline", None)

        handlers: list[urllib.request.BaseHandler] = [
            _DeadlineHandler(deadline_of), _NoRedirects()]
        if username:
            mgr = urllib.request.HTTPPasswordMgrWithDefaultRealm()
            mgr.add_password(None, self.url, username, password or "")
            handlers.append(urllib.request.HTTPDigestAuthHandler(mgr))
        self._opener = urllib.request.build_opener(*handlers)

    @classmethod
    def from_config(cls, cfg: CaptureConfig) -> OscClient:
        """A client with every setting of a ``[capture]`` section."""
        return cls(cfg.camera, username=cfg.username or None, password=cfg.password or None,
                   timeout_s=cfg.timeout_s, command_timeout_s=cfg.command_timeout_s,
                   request_deadline_s=cfg.request_deadline_s,
                   download_deadline_s=cfg.download_deadline_s,
                   max_json_bytes=cfg.max_json_bytes, max_download_bytes=cfg.max_download_bytes,
                   min_download_rate=cfg.min_download_rate,
                   min_download_window_s=cfg.min_download_window_s)

    # ------------------------------------------------------------------ HTTP
    @contextlib.contextmanager
    def _exchange(self, req: urllib.request.Request, deadline_s: float,
                  timeout: float | None = None
                  ) -> Iterator[tuple[http.client.HTTPResponse, _Deadline]]:
        """Open ``req`` under a deadline of ``deadline_s``; yields (response, deadline). The
        deadline holds until the block ends (reading the body included)."""
        with _Deadline(deadline_s) as deadline:
            self._local.deadline = deadline
            try:
                resp = self._open(req, deadline, timeout)
                try:
                    yield resp, deadline
                finally:
                    with contextlib.suppress(OSError, http.client.HTTPException):
                        resp.close()
            finally:
                self._local.deadline = None

    def _open(self, req: urllib.request.Request, deadline: _Deadline,
              timeout: float | None = None) -> http.client.HTTPResponse:
        where = req.full_url
        try:
            return self._opener.open(req, timeout=deadline.clamp(timeout or self.timeout_s))
        except urllib.error.HTTPError as exc:
            body = b""
            try:  # bytes; Debian 12's Python 3.11.2 gives str for its own "digest auth failed"
                raw = exc.read(_OSC_ERROR_BYTES)
                body = raw if isinstance(raw, bytes) else str(raw).encode("utf-8", "replace")
            except (OSError, http.client.HTTPException, ValueError):
                pass
            finally:
                with contextlib.suppress(OSError, http.client.HTTPException):
                    exc.close()
            refused = _osc_error(body)
            if refused is not None:
                raise _refusal(f"camera {where}", exc.code, refused) from None
            detail = body[:_ERROR_BODY_BYTES].decode("utf-8", "replace").strip()
            hint = ("check the user name and password (digest auth: THETA in client mode)"
                    if exc.code == 401 else
                    "grassd follows no redirects: check [capture] camera"
                    if 300 <= exc.code < 400 else
                    "the request was refused: check the command and options for this model"
                    if exc.code < 500 else "the camera failed: it may be busy or need a restart")
            raise CameraHttpError(f"camera {where} answered HTTP {exc.code} {exc.reason}"
                                  + (f" ({detail!r})" if detail else "") + f": {hint}",
                                  exc.code) from None
        except (urllib.error.URLError, OSError, http.client.HTTPException, ValueError) as exc:
            if deadline.over:
                self._late(f"camera {where}", deadline, CameraUnreachable)
            why = getattr(exc, "reason", exc)
            raise CameraUnreachable(f"camera {where} is unreachable ({why}): check the URL, "
                                    "that the camera is on and on the network") from None

    @staticmethod
    def _late(what: str, deadline: _Deadline, error: type[CameraError]) -> NoReturn:
        raise error(f"{what} did not finish within the {deadline.seconds:g} s deadline"
                    " (an answer trickling in, or a weak link): check the camera's "
                    "Wi-Fi, and restart it if it keeps happening") from None

    def _read_body(self, resp: http.client.HTTPResponse, deadline: _Deadline, cap: int,
                   sink: Callable[[bytes], object], what: str, error: type[CameraError],
                   too_big: type[CameraError]) -> int:
        """Copy ``resp``'s body into ``sink`` (called with each chunk) in chunks of
        :data:`CHUNK_BYTES`, at most ``cap`` bytes; returns the byte count. One byte beyond
        ``cap`` or a Content-Length beyond it is ``too_big``; a broken or short body or the
        deadline is ``error``."""
        declared = _content_length(resp)
        if declared is not None and declared > cap:
            raise too_big(f"{what} announces {declared} bytes ({_mib(declared)}), more than the "
                        f"cap of {cap} bytes ({_mib(cap)}); not read") from None
        n = 0
        while True:
            if deadline.expired:
                self._late(what, deadline, error)
            try:
                chunk = resp.read1(min(CHUNK_BYTES, cap + 1 - n))  # what has arrived
            except (OSError, http.client.HTTPException, ValueError) as exc:
                if deadline.over:
                    self._late(what, deadline, error)
                if isinstance(exc, http.client.IncompleteRead):
                    break  # the length check below says what arrived
                raise error(f"{what} broke off after {n} bytes: {exc!r}") from None
            if not chunk:
                break
            n += len(chunk)
            if n > cap:
                raise too_big(f"{what} is larger than the cap of {cap} bytes ({_mib(cap)}); "
                            "stopped reading") from None
            sink(chunk)
        if declared is not None and n != declared:
            if deadline.over:
                self._late(what, deadline, error)
            raise error(f"{what} is truncated: {n} of {declared} bytes arrived; the Wi-Fi link "
                        "may be weak") from None
        if deadline.expired and declared is None:
            self._late(what, deadline, error)  # the end of stream may be the watchdog's
        return n

    def _json(self, method: str, path: str, body: OscRequest | None = None) -> dict[str, Any]:
        data = None if body is None else json.dumps(body).encode("utf-8")
        req = urllib.request.Request(self.url + path, data=data, method=method, headers={
            "Content-Type": "application/json;charset=utf-8", "Accept": "application/json",
            "X-XSRF-Protected": "1"})
        where = f"camera {self.url}{path}"
        parts: list[bytes] = []
        with self._exchange(req, self.request_deadline_s) as (resp, deadline):
            self._read_body(resp, deadline, self.max_json_bytes, parts.append,
                            f"the answer of {where} (an OSC answer is a few kB)",
                            CameraUnreachable, CameraProtocolError)
        raw = b"".join(parts)
        try:
            out = json.loads(raw.decode("utf-8"))
        except (ValueError, RecursionError) as exc:  # JSONDecodeError, UnicodeDecodeError
            raise CameraProtocolError(f"{where} sent malformed JSON ({type(exc).__name__}: "
                                      f"{str(exc)[:120]}): {raw[:80]!r}; is this an OSC "
                                      "camera?") from None
        if not isinstance(out, dict):
            raise CameraProtocolError(f"{where} sent {type(out).__name__}, not a JSON object")
        return out

    # ------------------------------------------------------------------ API
    def info(self) -> CameraInfo:
        """``GET /osc/info``."""
        d = self._json("GET", "/osc/info")
        try:
            levels = d.get("apiLevel") or [1]
            return CameraInfo(str(d["manufacturer"]), str(d["model"]), str(d["serialNumber"]),
                              str(d["firmwareVersion"]), tuple(int(x) for x in levels))
        except (KeyError, TypeError, ValueError) as exc:
            raise CameraProtocolError(f"camera {self.url}/osc/info lacks {exc} "
                                      "(manufacturer, model, serialNumber, firmwareVersion)"
                                      ) from None

    def state(self) -> OscState:
        """``POST /osc/state``: ``{"fingerprint": ..., "state": {...}}``."""
        d = self._json("POST", "/osc/state", {})
        if not isinstance(d.get("state"), dict):
            raise CameraProtocolError(f"camera {self.url}/osc/state has no state object")
        return cast(OscState, d)

    def execute(self, name: str, parameters: OscParameters | None = None) -> OscResults:
        """Run command ``name`` and wait (polling ``/osc/commands/status``) until it is done;
        returns its ``results`` ({} when it has none)."""
        body = OscRequest(name=name)
        if parameters is not None:
            body["parameters"] = parameters
        cmd = cast(OscCommand, self._json("POST", "/osc/commands/execute", body))
        deadline = time.monotonic() + self.command_timeout_s
        while True:
            state = cmd.get("state")
            if state == "done":
                results = cmd.get("results", {})
                if not isinstance(results, dict):
                    raise CameraProtocolError(f"{name}: results is not a JSON object")
                return results
            if state == "error":
                raise _refusal(f"camera {self.url}", 200, {"name": name, **cmd})
            if state != "inProgress" or not isinstance(cmd.get("id"), str | int):
                raise CameraProtocolError(f"{name}: command state {state!r} without an id "
                                          "(expected done, inProgress with id, or error)")
            if time.monotonic() > deadline:
                raise CameraCommandTimeout(
                    f"{name} was still in progress after {self.command_timeout_s:g} s: the "
                    "camera may hang (restart it) or need a longer command timeout")
            time.sleep(self.poll_s)
            cmd = cast(OscCommand, self._json("POST", "/osc/commands/status",
                                              OscRequest(id=cmd["id"])))

    def set_options(self, **options: Unpack[OscOptions]) -> None:
        """``camera.setOptions`` with the given option values."""
        self.execute("camera.setOptions", {"options": options})

    def get_options(self, *names: str) -> OscOptions:
        """``camera.getOptions``: the current values of the named options."""
        res = self.execute("camera.getOptions", {"optionNames": list(names)})
        opts = res.get("options")
        if not isinstance(opts, dict):
            raise CameraProtocolError("camera.getOptions results lack an options object")
        return opts

    def ensure_image_mode(self) -> None:
        """Put the camera in still-image capture (``captureMode`` "image") unless it reports it
        already, then wait until it reports it: a THETA switches modes in its own time (at
        most ``command_timeout_s`` s, polled every ``poll_s`` s). A camera that refuses, or
        never reports the mode, raises :class:`~grassd.daemon.core.errors.CaptureModeRefused`
        quoting what it answered."""
        fix = ("a bracket needs still-image mode: stop any video or interval recording on the "
               "camera (its mode button or its app), check that no plug-in is running, then "
               "capture again; restart the camera if it persists")
        try:
            mode = self.get_options("captureMode").get("captureMode")
            if mode == IMAGE_MODE:
                return
            self.set_options(captureMode=IMAGE_MODE)
            deadline = time.monotonic() + self.command_timeout_s
            while (now := self.get_options("captureMode").get("captureMode")) != IMAGE_MODE:
                if time.monotonic() > deadline:
                    raise CaptureModeRefused(
                        f"camera {self.url} accepted captureMode {IMAGE_MODE!r} (it was "
                        f"{mode!r}) but still reports {now!r} after {self.command_timeout_s:g}"
                        f" s: {fix}", 200, command="camera.getOptions", code="", detail="")
                time.sleep(self.poll_s)
        except CaptureModeRefused:
            raise
        except CameraCommandRefused as exc:
            raise CaptureModeRefused(
                f"camera {self.url} refused still-image mode (captureMode {IMAGE_MODE!r}): "
                f"{exc.command} answered {exc.code} {exc.detail!r} (HTTP {exc.status}); {fix}",
                exc.status, command=exc.command, code=exc.code, detail=exc.detail) from None
        log.info("camera %s switched from captureMode %r to %r", self.url, mode, IMAGE_MODE)

    def take_picture(self) -> OscResults:
        """``camera.takePicture``: its results, with an absolute ``fileUrl``."""
        res = self.execute("camera.takePicture")
        if not isinstance(res.get("fileUrl"), str) or not res["fileUrl"]:
            raise CameraProtocolError("camera.takePicture finished without a fileUrl")
        return res

    def metadata(self, file_url: str) -> dict[str, ExifValue] | None:
        """THETA's ``camera._getMetadata``: the shot's EXIF as JSON, or None when the camera
        does not know the command (it is a RICOH extension)."""
        try:
            res = self.execute("camera._getMetadata", {"fileUrl": file_url})
        except (CameraProtocolError, CameraHttpError) as exc:
            log.debug("camera._getMetadata unavailable: %s", exc)
            return None
        exif = res.get("exif")
        return exif if isinstance(exif, dict) else None

    def own_url(self, file_url: str) -> str:
        """``file_url`` as served by the configured camera: its path and query on the
        configured scheme and host. A URL that is not http(s) raises CameraProtocolError."""
        got = urllib.parse.urlsplit(file_url)
        if got.scheme not in ("http", "https") or not got.path:
            raise CameraProtocolError(f"camera {self.url} named the file {file_url!r}, which is "
                                      "not an http(s) URL of a file on it; refusing to open it")
        own = urllib.parse.urlsplit(self.url)
        if (got.scheme, got.netloc) != (own.scheme, own.netloc):
            log.debug("fetching %s from the configured camera %s", file_url, self.url)
        return urllib.parse.urlunsplit((own.scheme, own.netloc, got.path, got.query, ""))

    def download(self, file_url: str, dest: Path) -> Path:
        """Download ``file_url`` (from the configured camera: :meth:`own_url`) to ``dest``,
        streamed through a hidden file beside it and renamed when whole: at most
        ``max_download_bytes``, within ``download_deadline_s``; the length must match
        Content-Length. Raises CameraDownloadError otherwise (nothing is left at ``dest``)."""
        req = urllib.request.Request(self.own_url(file_url), method="GET")
        part = dest.with_name(f".{dest.name}.part")
        try:
            with (self._exchange(req, self.download_deadline_s,
                                 timeout=max(self.timeout_s, 30.0)) as (resp, deadline),
                  part.open("wb") as fh):
                floor = _RateFloor(self.min_download_rate, self.min_download_window_s,
                                   f"download of {file_url}", fh.write)
                n = self._read_body(resp, deadline, self.max_download_bytes, floor.write,
                                    f"download of {file_url}", CameraDownloadError,
                                    CameraDownloadError)
            if not n:
                raise CameraDownloadError(f"download of {file_url} is empty")
            os.replace(part, dest)
        except BaseException:
            part.unlink(missing_ok=True)
            raise
        return dest


def _osc_error(body: bytes) -> OscCommand | None:
    """The OSC command object in an HTTP error's ``body`` when it is one in state "error"
    (``{"name": ..., "state": "error", "error": {"code": ..., "message": ...}}``), else None."""
    try:
        out = json.loads(body.decode("utf-8"))
    except (ValueError, RecursionError):
        return None
    if isinstance(out, dict) and out.get("state") == "error" and isinstance(out.get("error"),
                                                                          dict):
        return cast(OscCommand, out)
    return None


def _refusal(where: str, status: int, cmd: OscCommand) -> CameraCommandRefused:
    """The typed error of OSC command object ``cmd`` in state "error", answered by the camera
    at ``where`` with HTTP ``status``: its command, error code and message quoted."""
    err = cmd.get("error")
    if not isinstance(err, dict):
        err = OscErrorBody()
    name = str(cmd.get("name") or "a command")[:80]
    code = str(err.get("code") or "?")[:80]
    detail = str(err.get("message") or "")[:300]
    return CameraCommandRefused(
        f"{where} refused {name}: {code} {detail!r} (HTTP {status}): the camera does not take "
        "this command or value in its present state; check the options for this model "
        "(camera.getOptions of the option's name + 'Support' lists what it takes) and the "
        "camera's mode", status, command=name, code=code, detail=detail)


def _content_length(resp: http.client.HTTPResponse) -> int | None:
    """The Content-Length of ``resp`` as a number of bytes, or None when absent; a malformed
    one counts as absent (the cap still holds while reading)."""
    value = resp.headers.get("Content-Length")
    if value is None:
        return None
    try:
        n = int(str(value).strip()[:20])
    except ValueError:
        return None
    return n if n >= 0 else None


class CameraDownloadTooSlow(CameraDownloadError):
    """A download came slower than ``[capture] min_download_rate`` over its window."""


class _RateFloor:
    """A download's minimum rate (as curl's ``--speed-limit``): ``write(chunk)`` passes each
    chunk to ``sink`` and raises :class:`CameraDownloadTooSlow` once a window of ``window_s``
    seconds brought fewer than ``rate`` bytes/s (``rate`` 0: no floor)."""

    def __init__(self, rate: int, window_s: float, what: str,
                 sink: Callable[[bytes], object]) -> None:
        self.rate, self.window_s, self.what, self.sink = rate, window_s, what, sink
        self.mark_t, self.mark_n, self.n = time.monotonic(), 0, 0

    def write(self, chunk: bytes) -> None:
        self.sink(chunk)
        self.n += len(chunk)
        now = time.monotonic()
        if not self.rate or now - self.mark_t < self.window_s:
            return
        got = (self.n - self.mark_n) / (now - self.mark_t)
        if got < self.rate:
            raise CameraDownloadTooSlow(
                f"{self.what} came at {got:.0f} bytes/s over {now - self.mark_t:.1f} s, under "
                f"[capture] min_download_rate = {self.rate} bytes/s; stopped after {self.n} "
                "bytes: check the camera's Wi-Fi, and restart it if it keeps happening")
        self.mark_t, self.mark_n = now, self.n
