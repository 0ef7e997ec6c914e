"""An exposure bracket from an OSC camera, with each shot's real exposure.

The camera is first put in still-image capture (``captureMode`` "image",
:meth:`~grassd.daemon.camera.client.OscClient.ensure_image_mode`). The plan
(:class:`BracketPlan`): ``shots`` exposures ``ev_step`` EV apart around a centre
shutter, at a fixed ISO and white balance (manual program, ``exposureProgram = 1``), so that
only the shutter changes. The centre is either given or metered: one shot in ISO-priority
program (9) at the same ISO, whose real shutter (EXIF) becomes the centre. Shutter values are
snapped to the standard 1/3-EV series a camera accepts (:func:`snap_shutter`) and clamped to
``[min_shutter_s, max_shutter_s]``; a shot the clamp would merge into its neighbour at one end
is taken beyond the other end instead (:func:`plan_shutters`), so that a dark scene's bracket,
whose longest shots the 1 s limit drops, still reaches the short shutters its highlights need.

Each shot's real exposure comes from, in order: the EXIF of the downloaded file (ExposureTime,
FNumber, ISOSpeedRatings), THETA's ``camera._getMetadata``, and the camera's reported
``shutterSpeed`` option after the shot. A shot with none of these raises
:class:`~grassd.daemon.core.errors.ExposureMissing`: the merge needs real exposures, and a
requested one may differ from what the camera did.
"""

from __future__ import annotations

import contextlib
import logging
import math
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from grassd.daemon.camera.client import OscClient
from grassd.daemon.camera.config import CaptureConfig
from grassd.daemon.camera.messages import ExifValue, OscResults
from grassd.daemon.core.errors import (
    CameraDownloadError,
    CameraProtocolError,
    ExposureMissing,
)

if TYPE_CHECKING:
    from PIL import Image

log = logging.getLogger(__name__)

#: Standard shutter times (s) in 1/3-EV steps: the RICOH THETA Z1's list (Web API v2.1 option
#: shutterSpeed, manual program); other cameras use the same series.
SHUTTER_SPEEDS_S: tuple[float, ...] = (
    0.00004, 0.00005, 0.0000625, 0.00008, 0.0001, 0.000125, 0.00015625, 0.0002, 0.00025,
    0.0003125, 0.0004, 0.0005, 0.000625, 0.0008, 0.001, 0.00125, 0.0015625, 0.002, 0.0025,
    0.003125, 0.004, 0.005, 0.00625, 0.008, 0.01, 0.0125, 0.01666666, 0.02, 0.025, 0.03333333,
    0.04, 0.05, 0.06666666, 0.07692307, 0.1, 0.125, 0.16666666, 0.2, 0.25, 0.33333333, 0.4,
    0.5, 0.625, 0.76923076, 1.0, 1.3, 1.6, 2.0, 2.5, 3.2, 4.0, 5.0, 6.0, 8.0, 10.0, 13.0,
    15.0, 20.0, 25.0, 30.0, 40.0, 50.0, 60.0)
#: Exposure difference (EV) between requested and real shutter above which a warning is logged.
MISMATCH_EV: float = 0.5


@dataclass(frozen=True)
class BracketPlan:
    """What to shoot: ``shots`` exposures ``ev_step`` EV apart, ``iso``, ``aperture``
    (f-number; 0 = as the camera is), ``white_balance`` (an OSC whiteBalance name), centre
    shutter ``centre_shutter_s`` (s; None = meter first), shutter limits (s), ``file_format``
    "jpeg" or "raw+" (JPEG and DNG per shot, THETA Z1).
    Defaults: those of ``[capture]``
    (:class:`~grassd.daemon.camera.config.CaptureConfig`)."""

    shots: int = CaptureConfig.shots
    ev_step: float = CaptureConfig.ev_step
    iso: int = CaptureConfig.iso
    aperture: float = CaptureConfig.aperture
    white_balance: str = CaptureConfig.white_balance
    centre_shutter_s: float | None = None
    min_shutter_s: float = SHUTTER_SPEEDS_S[0]
    max_shutter_s: float = CaptureConfig.max_shutter_s
    file_format: str = CaptureConfig.file_format


@dataclass(frozen=True)
class Shot:
    """One shot: its ``path``, the requested shutter (s) and the real exposure: shutter
    ``exposure_s`` (s), ``iso``, ``f_number``, and where that came from (``source``);
    ``raw_path``: its DNG (RAW+ only)."""

    path: Path
    requested_s: float
    exposure_s: float
    iso: float
    f_number: float
    source: str
    raw_path: Path | None = None


def snap_shutter(seconds: float) -> float:
    """Nearest standard shutter time (s) of the 1/3-EV series cameras use (1/25000 ... 60 s;
    e.g. 1/500, 1/400, 1/320 ...), so a camera with a fixed list accepts it.

    >>> snap_shutter(0.0021)
    0.002
    """
    return min(SHUTTER_SPEEDS_S, key=lambda s: abs(math.log(s / seconds)))


def plan_shutters(plan: BracketPlan, centre_s: float) -> list[float]:
    """Shutter times (s, ascending, distinct, snapped and clamped) of ``plan`` around
    ``centre_s`` (s): ``shots`` of them ``ev_step`` EV apart. A shot that the clamp to
    ``[min_shutter_s, max_shutter_s]`` merges into its neighbour at one end is taken one step
    beyond the other end instead, while that end is inside its limit: a dark scene's bracket,
    whose longest shots the 1 s limit drops, reaches the shorter shutters that hold its
    highlights (and a bright one's the longer ones for its shadows). Never more than
    ``shots``; fewer only when both ends are at their limits.

    >>> plan_shutters(BracketPlan(shots=5, ev_step=2.0, max_shutter_s=1.0), 0.25)  # 4 s -> 1/250
    [0.004, 0.01666666, 0.06666666, 0.25, 1.0]
    """
    lo = -(plan.shots - 1) / 2.0  # the bracket's ends, in ev_step steps from the centre
    hi = -lo

    def ideal(step: float) -> float:
        return centre_s * 2.0 ** (step * plan.ev_step)

    def shutters() -> list[float]:
        steps = (lo + k for k in range(round(hi - lo) + 1))
        return sorted({snap_shutter(min(max(ideal(s), plan.min_shutter_s),
                                        plan.max_shutter_s)) for s in steps})

    out = shutters()
    while len(out) < plan.shots:
        if ideal(lo) > plan.min_shutter_s:
            lo -= 1.0
        elif ideal(hi) < plan.max_shutter_s:
            hi += 1.0
        else:
            break
        out = shutters()
    return out


def _ratio(v: ExifValue) -> float | None:
    """An EXIF number (float, int, IFDRational, "1/1000" or [num, den]) as float, or None."""
    try:
        if isinstance(v, str) and "/" in v:
            a, b = v.split("/", 1)
            return float(a) / float(b)
        if isinstance(v, list | tuple) and len(v) == 2:
            return float(v[0]) / float(v[1])
        f = float(v)
    except (TypeError, ValueError, ZeroDivisionError):
        return None
    return f if math.isfinite(f) and f > 0 else None


@contextlib.contextmanager
def open_shot(path: Path) -> Iterator[Image.Image]:
    """A shot opened with Pillow, its declared size checked before any pixel is decoded
    (Pillow's open reads the header only): at most :data:`grassd.sim.hdri.MAX_TEXELS` pixels,
    the largest panorama a bundle may hold (the merge keeps the shots' size). Raises
    CameraDownloadError naming the size for a larger one, an unreadable one, or one that
    Pillow's own decompression-bomb check refuses."""
    from PIL import Image

    from grassd.sim.hdri import MAX_TEXELS

    try:
        img = Image.open(path)
    except Image.DecompressionBombError as exc:
        raise CameraDownloadError(f"shot {path.name} declares too many pixels ({exc}); "
                                  "not decoded") from None
    except (OSError, ValueError, SyntaxError) as exc:  # UnidentifiedImageError is an OSError
        raise CameraDownloadError(f"shot {path.name} is not a readable image: {exc}") from None
    with img:
        width, height = img.size
        if width <= 0 or height <= 0 or width * height > MAX_TEXELS:
            raise CameraDownloadError(
                f"shot {path.name} declares {width} x {height} = {width * height} pixels, "
                f"over the limit of {MAX_TEXELS} (the largest panorama grassd takes); not "
                "decoded: set the camera's fileFormat to a smaller size")
        yield img


def file_exposure(path: Path) -> dict[str, float]:
    """ExposureTime (s), FNumber and ISO from a JPEG's EXIF ({} for the ones missing)."""
    from PIL import ExifTags

    try:
        with open_shot(path) as img:
            sub = img.getexif().get_ifd(ExifTags.IFD.Exif)
    except (OSError, ValueError, SyntaxError) as exc:
        raise CameraDownloadError(f"shot {path.name} is not a readable image: {exc}") from None
    out: dict[str, float] = {}
    for key, tag in (("exposure_s", ExifTags.Base.ExposureTime),
                     ("f_number", ExifTags.Base.FNumber),
                     ("iso", ExifTags.Base.ISOSpeedRatings)):
        v = _ratio(sub.get(tag))
        if v is not None:
            out[key] = v
    return out


def real_exposure(client: OscClient, result: OscResults, path: Path,
                  plan: BracketPlan) -> tuple[float, float, float, str]:
    """(shutter s, ISO, f-number, source) of a taken shot (module docstring)."""
    ex = file_exposure(path)
    source = "exif"
    if "exposure_s" not in ex:
        meta = client.metadata(result["fileUrl"]) or {}
        t = _ratio(meta.get("ExposureTime"))
        if t is not None:
            ex = {"exposure_s": t, **{k: v for k, v in (
                ("iso", _ratio(meta.get("PhotographicSensitivity"))),
                ("f_number", _ratio(meta.get("FNumber")))) if v is not None}, **ex}
            source = "camera._getMetadata"
    if "exposure_s" not in ex:
        opts = client.get_options("shutterSpeed", "iso")
        t = _ratio(opts.get("shutterSpeed"))
        if t is not None:
            ex["exposure_s"] = t
            ex.setdefault("iso", _ratio(opts.get("iso")) or plan.iso)
            source = "camera.getOptions"
    if "exposure_s" not in ex:
        raise ExposureMissing(
            f"shot {path.name}: the camera recorded no exposure time (no EXIF ExposureTime, "
            "no metadata, no shutterSpeed option); a bracket cannot be merged without it: "
            "check the camera's firmware and that it writes EXIF")
    return ex["exposure_s"], ex.get("iso", float(plan.iso)), ex.get("f_number", 1.0), source


def capture_bracket(client: OscClient, plan: BracketPlan, dest: Path) -> list[Shot]:
    """Shoot ``plan`` with ``client`` into directory ``dest``; shots sorted by exposure."""
    dest.mkdir(parents=True, exist_ok=True)
    client.ensure_image_mode()  # a camera left in video or interval mode takes no picture
    if plan.aperture:
        client.set_options(aperture=plan.aperture)
    centre = plan.centre_shutter_s
    if centre is None:  # meter: ISO priority at the bracket's ISO
        client.set_options(exposureProgram=9, iso=plan.iso, whiteBalance=plan.white_balance)
        res = client.take_picture()
        meter = client.download(res["fileUrl"], dest / "meter.jpg")
        centre, _, _, _ = real_exposure(client, res, meter, plan)
        meter.unlink()
        log.info("metered centre shutter %.6g s at ISO %d", centre, plan.iso)
    client.set_options(exposureProgram=1, iso=plan.iso, whiteBalance=plan.white_balance)
    if plan.file_format != "jpeg":  # keep the camera's size, change the type
        size = client.get_options("fileFormat").get("fileFormat")
        if not isinstance(size, dict):
            raise CameraProtocolError("camera.getOptions gave no fileFormat object")
        client.set_options(fileFormat={**size, "type": plan.file_format})
    shots = []
    for k, t in enumerate(plan_shutters(plan, centre)):
        client.set_options(shutterSpeed=t)
        res = client.take_picture()
        path = client.download(res["fileUrl"], dest / f"shot{k:02d}.jpg")
        exposure, iso, f_number, source = real_exposure(client, res, path, plan)
        if abs(math.log2(exposure / t)) > MISMATCH_EV:
            log.warning("shot %d: requested %.6g s but the camera exposed %.6g s (used)", k, t,
                        exposure)
        raw = None
        if plan.file_format == "raw+":
            if not isinstance(res.get("_dngFileUrl"), str):
                raise CameraProtocolError("camera.takePicture in raw+ gave no _dngFileUrl "
                                          "(RAW+ needs a THETA Z1 or later)")
            raw = client.download(res["_dngFileUrl"], dest / f"shot{k:02d}.dng")
        shots.append(Shot(path, t, exposure, iso, f_number, source, raw))
    shots.sort(key=lambda s: s.exposure_s * s.iso / s.f_number ** 2)
    return shots


def load_codes(shots: list[Shot]) -> list[np.ndarray]:
    """The shots' decoded 8-bit RGB codes, (H, W, 3) uint8 each."""
    from PIL import Image

    out = []
    for s in shots:
        try:
            with open_shot(s.path) as img:
                out.append(np.asarray(img.convert("RGB"), dtype=np.uint8))
        except (OSError, ValueError, SyntaxError, Image.DecompressionBombError) as exc:
            raise CameraDownloadError(f"shot {s.path.name} cannot be decoded ({exc}): the "
                                      "download may be corrupt") from None
    return out
