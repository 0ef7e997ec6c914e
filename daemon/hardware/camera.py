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

Commands: ``camera.setOptions`` / ``camera.getOptions`` (``exposureProgram``, ``iso``,
``shutterSpeed``, ``whiteBalance``, ``fileFormat``), ``camera.takePicture`` and THETA's
``camera._getMetadata`` (the shot's EXIF as JSON; optional, other cameras lack it).

A THETA in Wi-Fi client mode (on the site's network) requires HTTP digest authentication:
user name = the camera's ID printed on it (``THETAYN`` + the serial digits on a Z1,
``THETAYL...`` on a V), password = the serial digits unless changed; in access-point mode no
authentication is asked. Digest auth is urllib's ``HTTPDigestAuthHandler``.

Every failure is a typed :class:`~grassd.daemon.errors.CameraError` naming the URL.
Network traffic goes only to the configured URL: a ``fileUrl`` naming another host (a THETA
in client mode names its own IP, while the configuration may name it by host name) is fetched
from the configured one, and one that is not http(s) (``file:///etc/...``) is refused.
"""

from __future__ import annotations

import http.client
import json
import logging
import time
import urllib.error
import urllib.parse
import urllib.request
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from grassd.daemon.config.capture import CaptureConfig
from grassd.daemon.errors import (
    CameraCommandTimeout,
    CameraDownloadError,
    CameraHttpError,
    CameraProtocolError,
    CameraUnreachable,
)

log = logging.getLogger(__name__)

#: Seconds an HTTP request may take before the camera counts as unreachable ([capture]'s).
DEFAULT_TIMEOUT_S = CaptureConfig.timeout_s
#: Seconds a command (takePicture: exposure + stitching, up to a minute on a THETA Z1 at long
#: exposures) may stay inProgress ([capture]'s).
DEFAULT_COMMAND_TIMEOUT_S = CaptureConfig.command_timeout_s
#: Seconds between two /osc/commands/status polls.
DEFAULT_POLL_S = 0.25


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


class OscClient:
    """An OSC camera at ``url`` (e.g. ``http://192.168.1.1`` in access-point mode).

    ``username``/``password``: digest authentication (THETA in Wi-Fi client mode);
    ``timeout_s``: per HTTP request; ``command_timeout_s``: per command until done.
    """

    def __init__(self, url: str, *, username: str | None = None, password: str | None = None,
                 timeout_s: float = DEFAULT_TIMEOUT_S,
                 command_timeout_s: float = DEFAULT_COMMAND_TIMEOUT_S,
                 poll_s: float = DEFAULT_POLL_S) -> None:
        parsed = urllib.parse.urlparse(url)
        if parsed.scheme not in ("http", "https") or not parsed.netloc:
            raise CameraUnreachable(f"camera URL {url!r} is not an http:// URL "
                                    "(e.g. http://192.168.1.1)")
        self.url = url.rstrip("/")
        self.timeout_s = timeout_s
        self.command_timeout_s = command_timeout_s
        self.poll_s = poll_s
        handlers: list[urllib.request.BaseHandler] = []
        if username:
            mgr = urllib.request.HTTPPasswordMgrWithDefaultRealm()
            mgr.add_password(None, self.url, username, password or "")
            handlers.append(urllib.request.HTTPDigestAuthHandler(mgr))
        self._opener = urllib.request.build_opener(*handlers)

    # ------------------------------------------------------------------ HTTP
    def _open(self, req: urllib.request.Request, timeout: float | None = None) -> Any:
        where = req.full_url
        try:
            return self._opener.open(req, timeout=timeout or self.timeout_s)
        except urllib.error.HTTPError as exc:
            body = b""
            try:
                body = exc.read()[:300]
            except OSError:
                pass
            detail = body.decode("utf-8", "replace").strip()
            hint = ("check the user name and password (digest auth: THETA in client mode)"
                    if exc.code == 401 else
                    "the request was refused: check the command and options for this model"
                    if exc.code < 500 else "the camera failed: it may be busy or need a restart")
            raise CameraHttpError(f"camera {where} answered HTTP {exc.code} {exc.reason}"
                                  + (f" ({detail})" if detail else "") + f": {hint}",
                                  exc.code) from None
        except (urllib.error.URLError, TimeoutError, ConnectionError) as exc:
            why = getattr(exc, "reason", exc)
            raise CameraUnreachable(f"camera {where} is unreachable ({why}): check the URL, "
                                    "that the camera is on and on the network") from None

    def _json(self, method: str, path: str, body: dict[str, Any] | None = None) -> dict:
        data = None if body is None else json.dumps(body).encode("utf-8")
        req = urllib.request.Request(self.url + path, data=data, method=method, headers={
            "Content-Type": "application/json;charset=utf-8", "Accept": "application/json",
            "X-XSRF-Protected": "1"})
        with self._open(req) as resp:
            try:
                raw = resp.read()
            except (TimeoutError, ConnectionError, OSError, http.client.HTTPException) as exc:
                raise CameraUnreachable(f"camera {self.url}{path} stopped answering: "
                                        f"{exc}") from None
        try:
            out = json.loads(raw.decode("utf-8"))
        except (UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise CameraProtocolError(f"camera {self.url}{path} sent malformed JSON ({exc}): "
                                      f"{raw[:80]!r}; is this an OSC camera?") from None
        if not isinstance(out, dict):
            raise CameraProtocolError(f"camera {self.url}{path} sent {type(out).__name__}, "
                                      "not a JSON object")
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

    def state(self) -> dict[str, Any]:
        """``POST /osc/state``: ``{"fingerprint": ..., "state": {...}}``."""
        d = self._json("POST", "/osc/state", {})
        if not isinstance(d.get("state"), dict):
            raise CameraProtocolError(f"camera {self.url}/osc/state has no state object")
        return d

    def execute(self, name: str, parameters: dict[str, Any] | None = None) -> dict[str, Any]:
        """Run command ``name`` and wait (polling ``/osc/commands/status``) until it is done;
        returns its ``results`` ({} when it has none)."""
        body: dict[str, Any] = {"name": name}
        if parameters is not None:
            body["parameters"] = parameters
        cmd = self._json("POST", "/osc/commands/execute", body)
        deadline = time.monotonic() + self.command_timeout_s
        while True:
            state = cmd.get("state")
            if state == "done":
                results = cmd.get("results", {})
                if not isinstance(results, dict):
                    raise CameraProtocolError(f"{name}: results is not a JSON object")
                return results
            if state == "error":
                err = cmd.get("error") if isinstance(cmd.get("error"), dict) else {}
                raise CameraProtocolError(f"camera refused {name}: {err.get('code', '?')} "
                                          f"{err.get('message', '')}".rstrip())
            if state != "inProgress" or not isinstance(cmd.get("id"), str | int):
                raise CameraProtocolError(f"{name}: command state {state!r} without an id "
                                          "(expected done, inProgress with id, or error)")
            if time.monotonic() > deadline:
                raise CameraCommandTimeout(
                    f"{name} was still in progress after {self.command_timeout_s:g} s: the "
                    "camera may hang (restart it) or need a longer command timeout")
            time.sleep(self.poll_s)
            cmd = self._json("POST", "/osc/commands/status", {"id": cmd["id"]})

    def set_options(self, **options: Any) -> None:
        """``camera.setOptions`` with the given option values."""
        self.execute("camera.setOptions", {"options": options})

    def get_options(self, *names: str) -> dict[str, Any]:
        """``camera.getOptions``: the current values of the named options."""
        res = self.execute("camera.getOptions", {"optionNames": list(names)})
        opts = res.get("options")
        if not isinstance(opts, dict):
            raise CameraProtocolError("camera.getOptions results lack an options object")
        return opts

    def take_picture(self) -> dict[str, Any]:
        """``camera.takePicture``: its results, with an absolute ``fileUrl``."""
        res = self.execute("camera.takePicture")
        if not isinstance(res.get("fileUrl"), str) or not res["fileUrl"]:
            raise CameraProtocolError("camera.takePicture finished without a fileUrl")
        return res

    def metadata(self, file_url: str) -> dict[str, Any] | None:
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
        """Download ``file_url`` (from the configured camera: :meth:`own_url`) to ``dest``;
        the length must match Content-Length."""
        req = urllib.request.Request(self.own_url(file_url), method="GET")
        with self._open(req, timeout=max(self.timeout_s, 30.0)) as resp:
            expected = resp.headers.get("Content-Length")
            try:
                data = resp.read()
            except http.client.IncompleteRead as exc:
                raise CameraDownloadError(
                    f"download of {file_url} is truncated: {len(exc.partial)} of {expected} "
                    "bytes arrived; the Wi-Fi link may be weak") from None
            except (TimeoutError, ConnectionError, OSError, http.client.HTTPException) as exc:
                raise CameraDownloadError(f"download of {file_url} broke off: {exc}") from None
        if expected is not None and len(data) != int(expected):
            raise CameraDownloadError(f"download of {file_url} is truncated: {len(data)} of "
                                      f"{expected} bytes; the Wi-Fi link may be weak")
        if not data:
            raise CameraDownloadError(f"download of {file_url} is empty")
        dest.write_bytes(data)
        return dest
