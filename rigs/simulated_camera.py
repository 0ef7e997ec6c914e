"""A simulated Open Spherical Camera: a real HTTP server on 127.0.0.1 that photographs an HDRI.

``grassd camera sim --hdri FILE`` runs one; tests and ``--simulate-hardware`` start one in a
thread. It answers as an OSC API level 2 camera (a RICOH THETA Z1, Web API v2.1) does, with
the same JSON shapes, so the capture station (:mod:`grassd.daemon.camera.client`) and other
OSC clients drive it as they drive a THETA; only the URL differs:

* ``/osc/info``, ``/osc/state``, ``/osc/commands/execute``, ``/osc/commands/status`` and the
  shots under ``/files/``;
* commands ``camera.takePicture`` (inProgress, then done with ``fileUrl``),
  ``camera.setOptions`` / ``camera.getOptions``, ``camera.listFiles`` (``entries``,
  ``totalEntries``), ``camera.delete`` (``fileUrls``, or "all" / "image" / "video"),
  ``camera.reset`` (the options back to their defaults) and THETA's ``camera._getMetadata``;
* options ``captureMode``, ``exposureProgram``, ``exposureCompensation``, ``iso``,
  ``shutterSpeed``, ``whiteBalance``, ``_colorTemperature``, ``fileFormat`` and ``aperture``,
  each with its ``...Support`` value (:data:`OPTIONS`);
* the spec's error objects, with the HTTP status of the spec's table (:class:`ErrorCode`):
  ``unknownCommand`` for any other command, ``invalidParameterName`` for an option it does
  not have (getOptions never leaves out a name it was asked for), ``invalidParameterValue``,
  ``missingParameter``, ``tooManyParameters``, and ``disabledCommand`` for
  ``camera.takePicture`` in ``captureMode`` "video" (``capture_mode``, ``--capture-mode``),
  as a THETA left in video mode answers. The messages are the simulator's own.

Photographing (one shot at shutter ``t`` s, ``iso``, f-number ``N``): the scene radiance ``L``
(HDRI value x ``scene_scale``, cd/m^2-like units) gives the linear sensor signal
``x = 0.18 L t S / (K N^2)`` with the reflected-light meter constant K = 12.5 (ISO 2720), so a
metered exposure puts a mid-grey at 0.18 of full scale. Photon and read noise are added
(``full_well`` electrons at x = 1), then the camera's response curve (:class:`ResponseCurve`,
its own and never told to the merge), 8-bit quantisation and clipping, and the shot is served
as a JPEG (quality 95) whose EXIF holds the real exposure (with ``fileFormat`` type "raw+",
as a THETA Z1, also as a DNG of the same linear signal as a sensor with non-negative
spectral sensitivities responds to it, :func:`raw_sensor`, ``_dngFileUrl``). Shutter values are
those of the THETA Z1's list (:data:`SHUTTER_SPEEDS_S`), as a real camera's; an unsupported
value is refused with ``invalidParameterValue``.

Exposure programs: 1 manual (``shutterSpeed`` and ``iso`` as set); 2 normal and 9 ISO
priority: the camera meters, choosing the shutter that puts the median luminance at 0.18.

Fault knobs (:class:`Faults`, for tests): HTTP errors, malformed JSON, a takePicture that never
finishes, truncated downloads, shots without a recorded exposure. Each fault affects the next
``times`` requests it applies to (None: until cleared).
"""

from __future__ import annotations

import base64
import hashlib
import hmac
import io
import itertools
import json
import logging
import os
import threading
import time
import urllib.parse
import uuid
from collections.abc import Callable
from dataclasses import dataclass
from datetime import datetime
from enum import StrEnum
from functools import lru_cache
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from grassd.daemon.camera.bracket import SHUTTER_SPEEDS_S
from grassd.rigs import (
    SIM_CAMERA_CAPTURE_MODES,
    SIM_CAMERA_CURVE,
    SIM_CAMERA_CURVES,
    SIM_CAMERA_SCENE_SCALE,
    SIM_CAMERA_WIDTH,
)

log = logging.getLogger(__name__)

#: Reflected-light meter calibration constant K (ISO 2720, cd s / m^2 / ISO).
METER_K: float = 12.5
#: ISO values the simulated camera accepts (THETA Z1 list).
ISO_VALUES: tuple[int, ...] = (80, 100, 125, 160, 200, 250, 320, 400, 500, 640, 800, 1000,
                               1250, 1600, 2000, 2500, 3200, 4000, 5000, 6400)
#: White balance names accepted (OSC whiteBalance values).
WHITE_BALANCES: tuple[str, ...] = ("auto", "daylight", "shade", "cloudy-daylight",
                                   "incandescent", "fluorescent")
#: The lens' f-numbers (the THETA Z1's aperture option); the default is the smallest aperture,
#: as a sky capture wants (even so, at 1/25000 s the real sun, about 1.6e9 cd/m^2, clips: the
#: daemon restores it).
APERTURES: tuple[float, ...] = (2.1, 3.5, 5.6)
F_NUMBER: float = APERTURES[-1]
#: Exposure programs (OSC exposureProgram): 1 manual, 2 normal, 4 shutter priority, 9 ISO
#: priority.
EXPOSURE_PROGRAMS: tuple[int, ...] = (1, 2, 4, 9)
#: Exposure compensations (EV; THETA Z1 list), applied by the meter in programs 2 and 9.
EV_COMPENSATIONS: tuple[float, ...] = (-2.0, -1.7, -1.3, -1.0, -0.7, -0.3, 0.0, 0.3, 0.7, 1.0,
                                       1.3, 1.7, 2.0)
#: THETA's ``_colorTemperature`` range (K) and step, its ``_colorTemperatureSupport``.
COLOR_TEMPERATURE_K: dict[str, int] = {"maxTemperature": 10000, "minTemperature": 2500,
                                       "stepSize": 100}
#: The video formats of ``captureMode`` "video" (THETA Z1's two equirectangular ones).
VIDEO_FORMATS: tuple[dict[str, Any], ...] = (
    {"type": "mp4", "width": 3840, "height": 1920, "_codec": "H.264/MPEG-4 AVC"},
    {"type": "mp4", "width": 1920, "height": 960, "_codec": "H.264/MPEG-4 AVC"})
#: Most file URLs one ``camera.delete`` takes (THETA Web API v2.1).
MAX_DELETE_URLS: int = 128
#: The options the camera has; each also has ``NAME + "Support"`` (what it takes).
OPTIONS: tuple[str, ...] = ("captureMode", "exposureProgram", "exposureCompensation", "iso",
                            "shutterSpeed", "whiteBalance", "_colorTemperature", "fileFormat",
                            "aperture")


class CaptureMode(StrEnum):
    """OSC ``captureMode``: still images, or video (a THETA refuses takePicture in it)."""

    IMAGE = "image"
    VIDEO = "video"


class ErrorCode(StrEnum):
    """The OSC error codes the simulated camera answers (THETA Web API v2.1 errors table)."""

    UNKNOWN_COMMAND = "unknownCommand"
    DISABLED_COMMAND = "disabledCommand"
    MISSING_PARAMETER = "missingParameter"
    INVALID_PARAMETER_NAME = "invalidParameterName"
    INVALID_PARAMETER_VALUE = "invalidParameterValue"
    TOO_MANY_PARAMETERS = "tooManyParameters"

    @property
    def http_status(self) -> int:
        """The HTTP status the error comes with (the spec's table)."""
        forbidden = (ErrorCode.DISABLED_COMMAND, ErrorCode.TOO_MANY_PARAMETERS)
        return 403 if self in forbidden else 400


class OscRefusal(Exception):
    """A command the simulated camera refuses: its ``code`` and ``message``."""

    def __init__(self, code: ErrorCode, message: str) -> None:
        super().__init__(message)
        self.code, self.message = code, message


@dataclass(frozen=True)
class ShotFile:
    """One stored shot: its JPEG's ``name``, when it was ``taken``, its size (texels), its
    DNG's name (RAW+; None otherwise)."""

    name: str
    taken: datetime
    width: int
    height: int
    dng: str | None = None


@dataclass(frozen=True)
class ResponseCurve:
    """A camera's encoding of linear signal x (0..1 = full scale) into 0..1 codes:
    ``y = x^(1/gamma)``, then a shoulder ``(1 + s) y / (y + s)`` (s = ``shoulder``; none when
    infinite), so f(0) = 0 and f(1) = 1. Different cameras, different curves."""

    gamma: float = 2.2
    shoulder: float = float("inf")

    def encode(self, x: NDArray) -> NDArray[np.float64]:
        """Encoded value 0..1 of linear signal ``x`` (clipped to 0..1 first)."""
        y = np.clip(np.asarray(x, dtype=np.float64), 0.0, 1.0) ** (1.0 / self.gamma)
        if np.isinf(self.shoulder):
            return y
        return (1.0 + self.shoulder) * y / (y + self.shoulder)


#: Named curves: none of them is known to the merge (it recovers the curve from the shots).
CURVES: dict[str, ResponseCurve] = {
    "gamma22": ResponseCurve(2.2),
    "filmic": ResponseCurve(2.6, 0.6),
    "soft": ResponseCurve(1.8, 0.3),
}

assert tuple(CURVES) == SIM_CAMERA_CURVES
assert tuple(m.value for m in CaptureMode) == SIM_CAMERA_CAPTURE_MODES
#: Defaults of ``grassd camera sim`` and of :class:`SimCamera` (named in :mod:`grassd.rigs`)
SIM_WIDTH, SIM_CURVE, SIM_SCENE_SCALE = SIM_CAMERA_WIDTH, SIM_CAMERA_CURVE, SIM_CAMERA_SCENE_SCALE


@dataclass
class Faults:
    """What the simulated camera does wrong (tests). ``times``: how many more requests each
    active fault spoils (None: all until cleared)."""

    http_status: int | None = None      # answer /osc/* with this HTTP status
    malformed_json: bool = False        # answer /osc/* with broken JSON
    never_finish: bool = False          # takePicture stays inProgress forever
    truncated_download: bool = False    # send half of a file, with the full Content-Length
    missing_exposure: bool = False      # no ExposureTime in EXIF, options or metadata
    file_url_base: str | None = None    # fileUrl's scheme://host instead of the camera's own
    mode_locked: bool = False           # captureMode cannot change (disabledCommand)
    raw_file: bytes | None = None       # served as every RAW+ shot's DNG (a hostile file)
    times: int | None = None

    def spend(self) -> None:
        """One request was spoilt; clear every fault when ``times`` runs out."""
        if self.times is not None:
            self.times -= 1
            if self.times <= 0:
                self.clear()

    def clear(self) -> None:
        """Behave again."""
        self.http_status, self.malformed_json, self.never_finish = None, False, False
        self.truncated_download, self.missing_exposure, self.times = False, False, None
        self.file_url_base, self.mode_locked, self.raw_file = None, False, None


def jpeg_bytes(codes: NDArray[np.uint8], exif: dict[str, Any] | None) -> bytes:
    """Encode (H, W, 3) uint8 ``codes`` as a quality-95 JPEG whose EXIF holds ``exif``
    (ExposureTime s, FNumber, ISO, Make, Model, Software; any may be absent)."""
    from PIL import ExifTags, Image

    img = Image.fromarray(np.ascontiguousarray(codes), "RGB")
    ex = Image.Exif()
    exif = exif or {}
    for key, tag in (("Make", ExifTags.Base.Make), ("Model", ExifTags.Base.Model),
                     ("Software", ExifTags.Base.Software)):
        if key in exif:
            ex[tag] = str(exif[key])
    sub = ex.get_ifd(ExifTags.IFD.Exif)
    if "ExposureTime" in exif:
        sub[ExifTags.Base.ExposureTime] = float(exif["ExposureTime"])
    if "FNumber" in exif:
        sub[ExifTags.Base.FNumber] = float(exif["FNumber"])
    if "ISO" in exif:
        sub[ExifTags.Base.ISOSpeedRatings] = int(exif["ISO"])
    buf = io.BytesIO()
    img.save(buf, "JPEG", quality=95, subsampling=0, exif=ex)
    return buf.getvalue()


def _thumbnail(jpeg: bytes, size: int) -> bytes:
    """A JPEG of ``jpeg`` at most ``size`` texels across (listFiles' thumbnail)."""
    from PIL import Image

    with Image.open(io.BytesIO(jpeg)) as img:
        img.thumbnail((size, size))
        buf = io.BytesIO()
        img.save(buf, "JPEG", quality=80)
    return buf.getvalue()


@lru_cache(maxsize=1)
def raw_sensor() -> Any:
    """The simulated camera's RAW sensor: colour-science's Nikon D5100 sensitivities under
    D65 (:class:`grassd.calib.spectral_virtual_camera.SpectralVirtualCamera`), whose response
    to linear Rec.709 radiance has no negative entry, as a real sensor's has none; its DNG
    profile is the camera's maker-style matrix, which the checker's correction refines."""
    from grassd.calib.spectral_virtual_camera import SpectralVirtualCamera

    return SpectralVirtualCamera()


def dng_bytes(signal: NDArray, view: SensorView | None = None) -> bytes:
    """A DNG (the project's writer, :mod:`grassd.calib.dng`) of linear ``signal`` (H, W, 3,
    Rec.709 radiance, 1 = full scale) as :func:`raw_sensor` responds to it, on a sensor of
    twice the resolution (a whole 2 x 2 Bayer block per texel, as a real sensor resolves a sun
    of many photosites): mosaiced, clipped at the white level. With a :class:`SensorView`,
    ``signal`` is already the sensor's response and the DNG carries ``view.profile``."""
    import tempfile

    from grassd.calib.dng import DngCamera, mosaic, write_dng

    if view is None:
        sensor = raw_sensor()
        profile = np.asarray(sensor.profile)
        response = sensor.camera_rgb(np.asarray(signal, dtype=np.float64))
    else:
        profile, response = np.asarray(view.profile), np.asarray(signal, dtype=np.float64)
    cam = DngCamera(color_matrix=profile, model="SimCam Z1 RAW")
    fine = np.repeat(np.repeat(response, 2, axis=0), 2, axis=1)
    raw = mosaic(fine, cam)
    with tempfile.TemporaryDirectory() as d:
        path = write_dng(Path(d) / "shot.dng", raw, cam)
        return path.read_bytes()


@dataclass(frozen=True)
class SensorView:
    """What a ``scene_source`` may return instead of a map: the view's linear Rec.709
    ``radiance`` (H, W, 3; the JPEG and the meter read it) and the sensor's own ``raw``
    response to it (H, W, 3, the same units; computed elsewhere, e.g. spectrally), which the
    DNG holds with ``profile`` (3, 3, XYZ -> camera, the DNG's ColorMatrix1)."""

    radiance: NDArray
    raw: NDArray
    profile: NDArray


class SimCamera:
    """A simulated OSC camera photographing ``env`` (an (H, W, 3) linear radiance map, e.g.
    :func:`grassd.sim.hdri.load_hdri`) on ``host``:``port`` (0 = any free port).

    ``scene_scale``: radiance units per map unit (the light level; change it or :meth:`set_scene`
    between shots for another light); ``curve``: the response (a :data:`CURVES` name or a
    :class:`ResponseCurve`); ``full_well``: electrons at full scale (photon noise);
    ``username``/``password``: require HTTP digest auth as a THETA in client mode does.
    ``scene_source``: called at every shot for the map to photograph (a scene that changes,
    e.g. the simulated display of :mod:`grassd.rigs.simulated_display`), or for a
    :class:`SensorView` (the map and the sensor's own response to it, e.g.
    :mod:`grassd.rigs.spectral_display`'s).
    ``capture_mode``: the ``captureMode`` it starts (and resets) in, "image" or "video" (as a
    THETA someone filmed with; it then refuses takePicture until a client sets "image");
    ``mode_switch_s``: seconds a change of ``captureMode`` takes (a THETA switches in its own
    time), during which it still reports and behaves as the old mode.
    """

    def __init__(self, env: NDArray, *, scene_scale: float = SIM_SCENE_SCALE,
                 curve: str | ResponseCurve = SIM_CURVE, full_well: float = 20000.0,
                 read_noise: float = 2e-4, seed: int = 0, host: str = "127.0.0.1",
                 port: int = 0, username: str | None = None, password: str | None = None,
                 model: str = "grassd SimCam Z1", serial: str | None = None,
                 latency_s: float = 0.05,
                 scene_source: Callable[[], NDArray] | None = None,
                 capture_mode: str | CaptureMode = CaptureMode.IMAGE,
                 mode_switch_s: float = 0.0) -> None:
        self.curve = CURVES[curve] if isinstance(curve, str) else curve
        self.curve_name = curve if isinstance(curve, str) else "custom"
        self.env = np.ascontiguousarray(env, dtype=np.float32)
        self.scene_scale = float(scene_scale)
        self.full_well = float(full_well)
        self.read_noise = float(read_noise)
        self.rng = np.random.default_rng(seed)
        self.host, self.port = host, port
        self.username, self.password = username, password
        self.model = model
        digest = hashlib.sha1(repr(self.curve).encode()).hexdigest()[:8]  # noqa: S324
        self.serial = serial or f"SIM{digest}"
        self.latency_s = latency_s
        self.scene_source = scene_source
        self.faults = Faults()
        self.start_mode = CaptureMode(capture_mode)
        self.mode_switch_s = float(mode_switch_s)
        self._pending: tuple[CaptureMode, float] | None = None  # (mode, monotonic s when set)
        self.options: dict[str, Any] = {}
        self._other_format: dict[str, Any] = {}
        self.reset_options()
        self.shots_taken = 0
        self.files: dict[str, bytes] = {}
        self.shots: list[ShotFile] = []
        self.metadata: dict[str, dict[str, Any]] = {}
        self._commands: dict[str, dict[str, Any]] = {}
        self._ids = itertools.count(1)
        self._lock = threading.Lock()
        self._command_lock = threading.Lock()
        self._server: ThreadingHTTPServer | None = None
        self._thread: threading.Thread | None = None
        self._nonces: set[str] = set()

    # ------------------------------------------------------------------ lifecycle
    @property
    def url(self) -> str:
        """The camera's base URL (after :meth:`start`)."""
        return f"http://{self.host}:{self.port}"

    def start(self) -> SimCamera:
        """Serve in a background thread; returns self once listening."""
        cam = self

        class Handler(_Handler):
            camera = cam

        self._server = ThreadingHTTPServer((self.host, self.port), Handler)
        self._server.daemon_threads = True
        self.port = self._server.server_address[1]
        self._thread = threading.Thread(target=self._server.serve_forever, name="sim-camera",
                                        daemon=True)
        self._thread.start()
        log.info("simulated OSC camera (%s curve) on %s", self.curve_name, self.url)
        return self

    def stop(self) -> None:
        """Stop serving."""
        if self._server is not None:
            self._server.shutdown()
            self._server.server_close()
            self._server = None
        if self._thread is not None:
            self._thread.join(5)
            self._thread = None

    def __enter__(self) -> SimCamera:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def set_scene(self, env: NDArray | None = None, scene_scale: float | None = None) -> None:
        """Change what the camera sees: another map and/or light level."""
        with self._lock:
            if env is not None:
                self.env = np.ascontiguousarray(env, dtype=np.float32)
            if scene_scale is not None:
                self.scene_scale = float(scene_scale)

    # ------------------------------------------------------------------ photography
    @property
    def f_number(self) -> float:
        """The lens' current f-number (option ``aperture``)."""
        return float(self.options["aperture"])

    def gain(self, shutter_s: float, iso: float) -> float:
        """Linear sensor signal (full scale 1) per unit of the map (module docstring)."""
        return self.scene_scale * 0.18 * shutter_s * iso / (METER_K * self.f_number ** 2)

    def signal(self, shutter_s: float, iso: float) -> NDArray[np.float64]:
        """Noise-free linear sensor signal (full scale 1) of a shot (module docstring)."""
        return self.env.astype(np.float64) * self.gain(shutter_s, iso)

    def metered_shutter(self, iso: float, ev: float = 0.0) -> float:
        """The shutter (s, from the list) a meter chooses: median luminance at 0.18, times
        2^``ev`` (exposure compensation, EV)."""
        lum = self.env.astype(np.float64) @ np.array([0.2126, 0.7152, 0.0722])
        median = max(float(np.median(lum)) * self.scene_scale, 1e-9)
        t = METER_K * self.f_number ** 2 / (median * iso) * 2.0 ** ev
        return min(SHUTTER_SPEEDS_S, key=lambda s: abs(np.log(s / t)))

    def exposed(self, shutter_s: float, iso: float) -> NDArray[np.float64]:
        """The linear sensor signal of one shot with photon and read noise (not clipped)."""
        return self.noisy(self.signal(shutter_s, iso))

    def noisy(self, x: NDArray[np.float64]) -> NDArray[np.float64]:
        """Signal ``x`` (full scale 1) with photon and read noise added (not clipped)."""
        sigma = np.sqrt(np.clip(x, 0.0, 1.0) / self.full_well + self.read_noise ** 2)
        return x + self.rng.standard_normal(x.shape) * sigma

    def photograph(self, shutter_s: float, iso: float) -> NDArray[np.uint8]:
        """(H, W, 3) 8-bit codes of one shot: signal + noise -> response -> quantise."""
        return self.encode(self.exposed(shutter_s, iso))

    def encode(self, x: NDArray) -> NDArray[np.uint8]:
        """8-bit codes of linear signal ``x``: the response curve, quantised, clipped."""
        return np.clip(np.rint(self.curve.encode(x) * 255.0), 0, 255).astype(np.uint8)

    def _take(self) -> dict[str, Any]:
        view = None
        if self.scene_source is not None:
            seen = self.scene_source()
            view = seen if isinstance(seen, SensorView) else None
            self.set_scene(env=seen.radiance if view is not None else seen)
        o = self.options
        iso = o["iso"] if o["iso"] else 100
        if o["exposureProgram"] in (2, 9) or not o["shutterSpeed"]:
            ev = o["exposureCompensation"] if o["exposureProgram"] in (2, 9) else 0.0
            shutter = self.metered_shutter(iso, ev)
        else:
            shutter = float(o["shutterSpeed"])
        with self._lock:
            x = self.exposed(shutter, iso)
            raw = None if view is None else self.noisy(view.raw * self.gain(shutter, iso))
            self.shots_taken += 1
        codes = self.encode(x)
        name = f"R{self.shots_taken:07d}.JPG"
        base = self.faults.file_url_base or self.url
        out = {"fileUrl": f"{base}/files/{name}"}
        raw_name = None
        if o["fileFormat"].get("type") == "raw+":  # RAW+: a DNG of the same exposure too
            raw_name = name[:-4] + ".DNG"
            if self.faults.raw_file is not None:
                self.files[raw_name] = self.faults.raw_file
            elif view is None:
                self.files[raw_name] = dng_bytes(x)
            else:
                self.files[raw_name] = dng_bytes(raw, view)
            out["_dngFileUrl"] = f"{base}/files/{raw_name}"
        self.shots.append(ShotFile(name, datetime.now().astimezone(), codes.shape[1],
                                   codes.shape[0], raw_name))
        exif = {"Make": "grassd", "Model": self.model, "Software": "simcam 1.0",
                "ExposureTime": shutter, "FNumber": self.f_number, "ISO": iso}
        if self.faults.missing_exposure:
            del exif["ExposureTime"]
        self.files[name] = jpeg_bytes(codes, exif)
        meta = {k: v for k, v in exif.items()}
        meta["PhotographicSensitivity"] = meta.pop("ISO")
        self.metadata[out["fileUrl"]] = meta
        return out

    # ------------------------------------------------------------------ OSC
    @property
    def capture_mode(self) -> CaptureMode:
        """The current ``captureMode``."""
        return CaptureMode(self.options["captureMode"])

    def image_formats(self) -> list[dict[str, Any]]:
        """The still-image ``fileFormat`` values: JPEG and RAW+ at the map's size."""
        h, w = self.env.shape[:2]
        return [{"type": t, "width": w, "height": h} for t in ("jpeg", "raw+")]

    def reset_options(self) -> None:
        """Every option back to its default (``camera.reset``), in the starting capture mode."""
        video = self.start_mode is CaptureMode.VIDEO
        self.options = {
            "captureMode": self.start_mode.value, "exposureProgram": 2,
            "exposureCompensation": 0.0, "iso": 0, "shutterSpeed": 0, "whiteBalance": "auto",
            "_colorTemperature": 5000, "aperture": F_NUMBER,
            "fileFormat": dict(VIDEO_FORMATS[0] if video else self.image_formats()[0])}
        # the format of the other mode, restored when the mode switches back (a THETA keeps one
        # per mode)
        self._other_format = dict(self.image_formats()[0] if video else VIDEO_FORMATS[0])
        self._pending = None

    def support(self, name: str) -> Any:
        """The ``NAME + "Support"`` value of option ``name`` (what it takes, in the current
        capture mode)."""
        formats = (list(VIDEO_FORMATS) if self.capture_mode is CaptureMode.VIDEO
                   else self.image_formats())
        return {"captureMode": [m.value for m in CaptureMode],
                "exposureProgram": list(EXPOSURE_PROGRAMS),
                "exposureCompensation": list(EV_COMPENSATIONS),
                "iso": [0, *ISO_VALUES], "shutterSpeed": [0, *SHUTTER_SPEEDS_S],
                "whiteBalance": [*WHITE_BALANCES, "_colorTemperature"],
                "_colorTemperature": dict(COLOR_TEMPERATURE_K),
                "fileFormat": formats, "aperture": list(APERTURES)}[name]

    def info(self) -> dict[str, Any]:
        """The ``/osc/info`` object."""
        return {"manufacturer": "grassd", "model": self.model, "serialNumber": self.serial,
                "firmwareVersion": "1.0.0", "supportUrl": "https://example.invalid/",
                "gps": False, "gyro": False, "uptime": 1, "api": ["/osc/info", "/osc/state",
                "/osc/commands/execute", "/osc/commands/status"],
                "endpoints": {"httpPort": self.port, "httpUpdatesPort": self.port},
                "apiLevel": [2]}

    def execute(self, name: str, params: dict[str, Any]) -> dict[str, Any]:
        """Run one command; returns the OSC command object (state done, inProgress or
        error)."""
        commands: dict[str, Callable[[dict[str, Any]], dict[str, Any] | None]] = {
            "camera.setOptions": self._set_options, "camera.getOptions": self._get_options,
            "camera.listFiles": self._list_files, "camera.delete": self._delete,
            "camera.reset": self._reset, "camera._getMetadata": self._get_metadata}
        with self._command_lock:
            self._settle()
            try:
                if name == "camera.takePicture":
                    return self._take_picture()
                run = commands.get(name)
                if run is None:
                    raise OscRefusal(ErrorCode.UNKNOWN_COMMAND,
                                     f"command {name} is not supported")
                results = run(params)
            except OscRefusal as exc:
                return _error(name, exc.code, exc.message)
        out: dict[str, Any] = {"name": name, "state": "done"}
        if results is not None:
            out["results"] = results
        return out

    def status(self, cid: Any) -> dict[str, Any]:
        """The ``/osc/commands/status`` object of command ``cid``."""
        entry = self._commands.get(str(cid))
        if entry is None:
            return _error("camera.status", ErrorCode.INVALID_PARAMETER_VALUE,
                          f"no command id {cid!r}")
        if not entry["never"] and time.monotonic() >= entry["ready_at"]:
            entry["state"] = "done"
            entry["progress"] = {"completion": 1.0}
        return _public(entry)

    def _take_picture(self) -> dict[str, Any]:
        name = "camera.takePicture"
        if self.capture_mode is not CaptureMode.IMAGE:
            raise OscRefusal(ErrorCode.DISABLED_COMMAND,
                             f"{name} is disabled in captureMode {self.capture_mode.value!r}: "
                             "set captureMode to 'image' first")
        cid = str(next(self._ids))
        entry: dict[str, Any] = {"name": name, "state": "inProgress", "id": cid,
                                 "progress": {"completion": 0.0},
                                 "ready_at": time.monotonic() + self.latency_s,
                                 "never": self.faults.never_finish}
        if self.faults.never_finish:
            self.faults.spend()
        else:
            entry["results"] = self._take()
            if self.faults.missing_exposure:
                self.faults.spend()
        self._commands[cid] = entry
        return _public(entry)

    def _set_options(self, params: dict[str, Any]) -> None:
        opts = params.get("options")
        if not isinstance(opts, dict):
            raise OscRefusal(ErrorCode.MISSING_PARAMETER, "options (an object) is required")
        for key in opts:  # every name and value is checked before any is set
            if key not in OPTIONS:
                raise OscRefusal(ErrorCode.INVALID_PARAMETER_NAME,
                                 f"{key} is not an option that can be set")
        saved = dict(self.options), self._other_format, self._pending
        try:
            if "captureMode" in opts:
                self._switch_mode(opts["captureMode"])
            for key, value in opts.items():
                problem = self._check_option(key, value)
                if problem:
                    raise OscRefusal(ErrorCode.INVALID_PARAMETER_VALUE, problem)
        except OscRefusal:
            self.options, self._other_format, self._pending = saved
            raise
        self.options.update({k: v for k, v in opts.items() if k != "captureMode"})
        return None

    def _switch_mode(self, value: Any) -> None:
        """Go into captureMode ``value``: the file format becomes that mode's."""
        modes = [m.value for m in CaptureMode]
        if value not in modes:
            raise OscRefusal(ErrorCode.INVALID_PARAMETER_VALUE,
                             f"captureMode {value!r} is not supported (one of {modes})")
        mode = CaptureMode(value)
        if mode is self.capture_mode:
            self._pending = None
            return
        if self.faults.mode_locked:
            self.faults.spend()
            raise OscRefusal(ErrorCode.DISABLED_COMMAND,
                             "captureMode cannot change while the camera records a video")
        self._pending = mode, time.monotonic() + self.mode_switch_s
        self._settle()

    def _settle(self) -> None:
        """Finish a pending change of captureMode once its time has come."""
        if self._pending is None or time.monotonic() < self._pending[1]:
            return
        mode, self._pending = self._pending[0], None
        self.options["fileFormat"], self._other_format = (self._other_format,
                                                          self.options["fileFormat"])
        self.options["captureMode"] = mode.value

    def _get_options(self, params: dict[str, Any]) -> dict[str, Any]:
        names = params.get("optionNames")
        if not isinstance(names, list) or not all(isinstance(n, str) for n in names):
            raise OscRefusal(ErrorCode.MISSING_PARAMETER,
                             "optionNames (an array of option names) is required")
        out: dict[str, Any] = {}
        for n in names:
            if n in OPTIONS:
                out[n] = self.options[n]
            elif n.endswith("Support") and n[: -len("Support")] in OPTIONS:
                out[n] = self.support(n[: -len("Support")])
            else:
                raise OscRefusal(ErrorCode.INVALID_PARAMETER_NAME, f"{n} is not an option")
        if self.faults.missing_exposure:
            out.pop("shutterSpeed", None)
        return {"options": out}

    def _list_files(self, params: dict[str, Any]) -> dict[str, Any]:
        for key in ("fileType", "entryCount", "maxThumbSize"):
            if key not in params:
                raise OscRefusal(ErrorCode.MISSING_PARAMETER, f"{key} is required")
        kind, count = params["fileType"], params["entryCount"]
        thumb, start = params["maxThumbSize"], params.get("startPosition", 0)
        detail = params.get("_detail", True)
        if kind not in ("all", "image", "video"):
            raise OscRefusal(ErrorCode.INVALID_PARAMETER_VALUE,
                             f"fileType {kind!r} is not one of all, image, video")
        for key, value in (("entryCount", count), ("startPosition", start),
                           ("maxThumbSize", 0 if thumb is None else thumb)):
            if not isinstance(value, int) or isinstance(value, bool) or value < 0:
                raise OscRefusal(ErrorCode.INVALID_PARAMETER_VALUE,
                                 f"{key} {value!r} is not a whole number >= 0")
        if not isinstance(detail, bool):
            raise OscRefusal(ErrorCode.INVALID_PARAMETER_VALUE, "_detail is not a boolean")
        shots = [] if kind == "video" else self.shots[::-1]  # newest first; no videos here
        return {"entries": [self._entry(f, detail, thumb or 0)
                            for f in shots[start:start + count]],
                "totalEntries": len(shots)}

    def _entry(self, shot: ShotFile, detail: bool, thumb: int) -> dict[str, Any]:
        """The listFiles entry of ``shot`` (the THETA's fields)."""
        data = self.files[shot.name]
        out: dict[str, Any] = {"name": shot.name, "fileUrl": f"{self.url}/files/{shot.name}",
                               "size": len(data), "isProcessed": True, "previewUrl": ""}
        if not detail:
            out["dateTime"] = shot.taken.strftime("%Y:%m:%d %H:%M:%S")
            return out
        zone = shot.taken.strftime("%z")
        out.update({"dateTimeZone": shot.taken.strftime("%Y:%m:%d %H:%M:%S")
                    + f"{zone[:3]}:{zone[3:]}", "width": shot.width, "height": shot.height,
                    "_projectionType": "Equirectangular"})
        if thumb:
            small = _thumbnail(data, thumb)
            out.update({"thumbnail": base64.b64encode(small).decode("ascii"),
                        "_thumbSize": len(small)})
        return out

    def _delete(self, params: dict[str, Any]) -> None:
        urls = params.get("fileUrls")
        if not isinstance(urls, list) or not urls or not all(isinstance(u, str) for u in urls):
            raise OscRefusal(ErrorCode.MISSING_PARAMETER,
                             "fileUrls (an array of file URLs) is required")
        if len(urls) > MAX_DELETE_URLS:
            raise OscRefusal(ErrorCode.TOO_MANY_PARAMETERS,
                             f"{len(urls)} file URLs, at most {MAX_DELETE_URLS} at once")
        special = {"all", "image", "video"} & set(urls)
        if special and len(urls) > 1:
            raise OscRefusal(ErrorCode.INVALID_PARAMETER_VALUE,
                             f"{sorted(special)[0]!r} must be given alone")
        if special:
            doomed = [] if urls == ["video"] else list(self.shots)
        else:
            by_name = {f.name: f for f in self.shots}
            doomed = []
            for u in urls:  # every URL must name a file, else nothing is deleted
                shot = by_name.get(urllib.parse.urlsplit(u).path.rsplit("/", 1)[-1])
                if shot is None or not urllib.parse.urlsplit(u).path.startswith("/files/"):
                    raise OscRefusal(ErrorCode.INVALID_PARAMETER_VALUE,
                                     f"no such file {u!r}; nothing deleted")
                doomed.append(shot)
        for shot in doomed:
            self.shots.remove(shot)
            self.files.pop(shot.name, None)
            if shot.dng:
                self.files.pop(shot.dng, None)
            for url in [u for u in self.metadata if u.endswith(f"/files/{shot.name}")]:
                del self.metadata[url]
        return None

    def _reset(self, params: dict[str, Any]) -> None:
        self.reset_options()
        return None

    def _get_metadata(self, params: dict[str, Any]) -> dict[str, Any]:
        url = params.get("fileUrl")
        if not isinstance(url, str):
            raise OscRefusal(ErrorCode.MISSING_PARAMETER, "fileUrl is required")
        if url not in self.metadata:
            raise OscRefusal(ErrorCode.INVALID_PARAMETER_VALUE, f"no such file {url!r}")
        return {"exif": self.metadata[url], "xmp": {}}

    def _check_option(self, key: str, value: Any) -> str | None:
        """Why ``value`` is not one option ``key`` takes (None: it is)."""
        number = isinstance(value, int | float) and not isinstance(value, bool)
        if key == "shutterSpeed":
            if not number or (value != 0 and not any(abs(value - s) <= 1e-9 + 1e-6 * s
                                                     for s in SHUTTER_SPEEDS_S)):
                return f"shutterSpeed {value!r} is not a supported value"
        elif key == "iso":
            if not number or (value != 0 and value not in ISO_VALUES):
                return f"iso {value!r} is not a supported value"
        elif key == "exposureProgram":
            if not number or value not in EXPOSURE_PROGRAMS:
                return f"exposureProgram {value!r} is not supported"
        elif key == "exposureCompensation":
            if not number or not any(abs(value - e) < 1e-6 for e in EV_COMPENSATIONS):
                return (f"exposureCompensation {value!r} is not supported (one of "
                        f"{list(EV_COMPENSATIONS)})")
        elif key == "whiteBalance":
            if value not in self.support("whiteBalance"):
                return f"whiteBalance {value!r} is not supported"
        elif key == "_colorTemperature":
            k = COLOR_TEMPERATURE_K
            if (not number or not k["minTemperature"] <= value <= k["maxTemperature"]
                    or value % k["stepSize"]):
                return (f"_colorTemperature {value!r} is not supported ({k['minTemperature']}"
                        f"-{k['maxTemperature']} K in steps of {k['stepSize']})")
        elif key == "fileFormat":
            if value not in self.support("fileFormat"):
                return (f"fileFormat {value!r} is not supported in captureMode "
                        f"{self.capture_mode.value!r} (one of {self.support('fileFormat')})")
        elif key == "aperture":
            if value not in APERTURES:
                return f"aperture {value} is not supported (one of {APERTURES})"
        return None


    # ------------------------------------------------------------------ digest auth
    def _check_auth(self, header: str | None, method: str) -> bool:
        """RFC 7616 digest (MD5, qop=auth) check of an Authorization header."""
        if self.username is None:
            return True
        if not header or not header.startswith("Digest "):
            return False
        fields: dict[str, str] = {}
        for part in header[7:].split(","):
            if "=" in part:
                k, v = part.strip().split("=", 1)
                fields[k] = v.strip('"')
        if fields.get("username") != self.username or fields.get("nonce") not in self._nonces:
            return False

        def md5(s: str) -> str:
            return hashlib.md5(s.encode()).hexdigest()  # noqa: S324 - RFC 7616 MD5

        ha1 = md5(f"{self.username}:{fields.get('realm')}:{self.password or ''}")
        ha2 = md5(f"{method}:{fields.get('uri')}")
        expect = md5(f"{ha1}:{fields['nonce']}:{fields.get('nc')}:{fields.get('cnonce')}:"
                     f"{fields.get('qop')}:{ha2}")
        return hmac.compare_digest(expect, fields.get("response", ""))

    def new_nonce(self) -> str:
        """A fresh server nonce for a digest challenge."""
        nonce = uuid.uuid4().hex
        self._nonces.add(nonce)
        return nonce


def _error(name: str, code: ErrorCode, message: str) -> dict[str, Any]:
    return {"name": name, "state": "error", "error": {"code": code.value, "message": message}}


def _public(entry: dict[str, Any]) -> dict[str, Any]:
    out = {k: v for k, v in entry.items() if k not in ("ready_at", "never")}
    if out.get("state") != "done":
        out.pop("results", None)
    return out


def _http_status(out: dict[str, Any]) -> int:
    """The HTTP status of OSC command object ``out``: 200, or its error code's."""
    if out.get("state") != "error":
        return 200
    return ErrorCode(out["error"]["code"]).http_status


class _Handler(BaseHTTPRequestHandler):
    camera: SimCamera
    protocol_version = "HTTP/1.1"

    def log_message(self, fmt: str, *args: Any) -> None:  # quiet
        log.debug("sim camera: " + fmt, *args)

    def _send(self, status: int, body: bytes, ctype: str = "application/json; charset=utf-8",
              length: int | None = None, headers: dict[str, str] | None = None) -> None:
        self.send_response(status)
        self.send_header("Content-Type", ctype)
        self.send_header("Content-Length", str(len(body) if length is None else length))
        self.send_header("X-Content-Type-Options", "nosniff")
        for k, v in (headers or {}).items():
            self.send_header(k, v)
        self.end_headers()
        self.wfile.write(body)
        self.wfile.flush()

    def _authorised(self) -> bool:
        cam = self.camera
        if cam._check_auth(self.headers.get("Authorization"), self.command):
            return True
        challenge = (f'Digest realm="sim-camera", qop="auth", nonce="{cam.new_nonce()}", '
                     'algorithm=MD5')
        self._send(401, b'{"error": "unauthorized"}', headers={"WWW-Authenticate": challenge})
        return False

    def _faulty(self) -> bool:
        f = self.camera.faults
        if f.http_status is not None:
            status = f.http_status
            f.spend()
            self._send(status, json.dumps({"error": {"code": "serviceUnavailable",
                                                     "message": "simulated fault"}}).encode())
            return True
        if f.malformed_json:
            f.spend()
            self._send(200, b'{"name": "camera.takePicture", "state": ')
            return True
        return False

    def _body(self) -> dict[str, Any]:
        n = int(self.headers.get("Content-Length") or 0)
        raw = self.rfile.read(n) if n else b""
        try:
            data = json.loads(raw or b"{}")
        except json.JSONDecodeError:
            data = None
        return data if isinstance(data, dict) else {}

    def do_GET(self) -> None:  # noqa: N802 - http.server API
        if not self._authorised():
            return
        cam = self.camera
        if self.path == "/osc/info":
            if not self._faulty():
                self._send(200, json.dumps(cam.info()).encode())
            return
        if self.path.startswith("/files/"):
            data = cam.files.get(self.path[len("/files/"):])
            if data is None:
                self._send(404, b'{"error": "no such file"}')
                return
            if cam.faults.truncated_download:
                cam.faults.spend()
                self._send(200, data[: len(data) // 2], "image/jpeg", length=len(data))
                self.close_connection = True
                return
            self._send(200, data, "image/jpeg")
            return
        self._send(404, b'{"error": "not found"}')

    def do_POST(self) -> None:  # noqa: N802 - http.server API
        body = self._body()
        if not self._authorised():
            return
        if self._faulty():
            return
        cam = self.camera
        if self.path == "/osc/state":
            out = {"fingerprint": f"FIG_{cam.shots_taken}", "state": {
                "batteryLevel": 1.0, "storageUri": "sim", "_captureStatus": "idle",
                "_apiVersion": 2}}
        elif self.path == "/osc/commands/execute":
            params = body.get("parameters") if isinstance(body.get("parameters"), dict) else {}
            out = cam.execute(str(body.get("name")), params)
        elif self.path == "/osc/commands/status":
            out = cam.status(body.get("id"))
        else:
            self._send(404, b'{"error": "not found"}')
            return
        self._send(_http_status(out), json.dumps(out).encode())


def sim_camera_from_file(hdri: str | os.PathLike[str], *, width: int | None = None,
                         **kwargs: Any) -> SimCamera:
    """A :class:`SimCamera` photographing the HDRI file ``hdri`` (downsampled to at most
    ``width`` texels across by whole factors; default: as stored)."""
    from grassd.sim.hdri import downsample, load_hdri

    env = load_hdri(hdri)
    if width is not None and env.shape[1] > width:
        factor = env.shape[1] // width
        while env.shape[0] % factor:
            factor -= 1
        if factor > 1:
            env = downsample(env, factor)
    return SimCamera(env, **kwargs)


def start_site_camera(hw: Any, width: int = 256) -> SimCamera:
    """Start a simulated camera photographing the packaged site panorama at the light level of
    the simulated lux sensor of ``hw`` (a
    :class:`grassd.rigs.simulated_site.SimulatedHardware`; horizontal illuminance of the
    photographed scene = its lux), for ``--simulate-hardware``."""
    from grassd.sim.hdri import default_site_hdri
    from grassd.sim.lighting import horizontal_illuminance

    cam = sim_camera_from_file(default_site_hdri(), width=width)
    lux = float(getattr(hw, "lux", 5000.0))
    cam.set_scene(scene_scale=lux / horizontal_illuminance(cam.env))
    return cam.start()
