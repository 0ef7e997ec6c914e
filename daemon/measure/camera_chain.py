"""The measuring camera: its shots, and the colour chain from its RAW to CIELAB.

The chain is ``grassd validate``'s (:mod:`grassd.calib.checker_photo`), with the colour
checker photographed once, at set-up, instead of in every capture:

* **Set-up** (:func:`setup_from_checker`): the checker lying at the display, photographed with
  the measuring camera, gives the LibRaw white balance that develops its grey patch to the grey's
  reference colour (:func:`~grassd.calib.checker_photo.checker_white_balance`), the scale
  ``k`` that puts that grey at Y = 0.18, and the 3 x 3 colour correction from the analytic
  virtual checker to the photographed one (with the scale ``s`` of the white-card-normalised
  simulation, :func:`~grassd.calib.checker_photo.virtual_checker`): the same ``ccm`` that
  ``validate`` hands the simulation.
* **A measurement shot**: its DNG developed (half size: one texel per 2 x 2 Bayer block) with that
  white balance, to linear ProPhoto, scaled by ``k`` times the ratio of the set-up exposure to the
  shot's (shutter x ISO / f-number^2) times the ratio of the set-up lux to the lux now: what the
  checker's grey would read if it lay there now. The simulation is normalised by the white card
  under the light now, so both sides share their white.

Units: exposure values s x ISO / f-number^2; lux; colours linear ProPhoto (grey card Y = 0.18).
"""

from __future__ import annotations

import functools
import json
import logging
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING, NotRequired, TypedDict

import numpy as np
from numpy.typing import NDArray

from grassd.daemon.core.errors import DaemonError

if TYPE_CHECKING:
    from grassd.daemon.camera.client import OscClient

log = logging.getLogger(__name__)


class MeasureSetupError(DaemonError):
    """The measuring camera has no usable set-up (photograph the checker: grassd measure
    setup)."""


@dataclass(frozen=True)
class Exposure:
    """A shot's exposure: shutter (s), ISO and f-number."""

    shutter_s: float
    iso: float
    f_number: float

    @property
    def value(self) -> float:
        """Relative exposure, shutter x ISO / f-number^2 (signal per unit radiance)."""
        return self.shutter_s * self.iso / self.f_number ** 2


class ExposureJson(TypedDict):
    """An :class:`Exposure` as ``setup.json`` holds it."""

    shutter_s: float
    iso: float
    f_number: float


class MeasureSetupJson(TypedDict):
    """A :class:`MeasureSetup` as ``setup.json`` holds it (lists read back where it wrote
    tuples; ``ccm_de00`` and ``sensor`` absent from a set-up made before they were kept)."""

    white_balance: Sequence[float]
    scale: float
    exposure: ExposureJson
    lux: float
    ccm: Sequence[Sequence[float]]
    chart: str
    photo: str
    made_at: str
    ccm_de00: NotRequired[Sequence[float] | None]
    sensor: NotRequired[Sequence[int] | None]


@dataclass(frozen=True)
class Shot:
    """One measurement photo: its DNG ``raw_path`` and its ``exposure``."""

    raw_path: Path
    exposure: Exposure


@dataclass(frozen=True)
class MeasureSetup:
    """The measuring camera's colour chain (module docstring): LibRaw ``white_balance``
    (R, G, B, G2), ``scale`` k (grey at Y = 0.18 in the set-up shot), the set-up shot's
    ``exposure`` and ``lux``, ``ccm`` (3, 3) for the simulation (scale included), the
    ``chart`` and the ``photo`` it came from, ``made_at`` (ISO 8601 UTC), ``ccm_de00`` the
    correction's mean and largest leave-one-out CIEDE2000 on the patches (each patch predicted
    by the 3x3 fitted to the others; the fitting residual in a set-up made before; None: a
    set-up made before either was kept), ``sensor`` the set-up shot's sensor (width, height
    in photosites; None: a set-up made before it was kept), which every measurement shot must
    have."""

    white_balance: tuple[float, float, float, float]
    scale: float
    exposure: Exposure
    lux: float
    ccm: tuple[tuple[float, ...], ...]
    chart: str
    photo: str
    made_at: str
    ccm_de00: tuple[float, float] | None = None
    sensor: tuple[int, int] | None = None

    def to_json(self) -> MeasureSetupJson:
        """The set-up as JSON (``setup.json``)."""
        e = self.exposure
        return {"white_balance": self.white_balance, "scale": self.scale,
                "exposure": {"shutter_s": e.shutter_s, "iso": e.iso, "f_number": e.f_number},
                "lux": self.lux, "ccm": self.ccm, "chart": self.chart, "photo": self.photo,
                "made_at": self.made_at, "ccm_de00": self.ccm_de00, "sensor": self.sensor}

    @classmethod
    def from_json(cls, d: MeasureSetupJson) -> MeasureSetup:
        """Read :meth:`to_json`'s form back."""
        return cls(white_balance=tuple(d["white_balance"]), scale=float(d["scale"]),
                   exposure=Exposure(**d["exposure"]), lux=float(d["lux"]),
                   ccm=tuple(tuple(r) for r in d["ccm"]), chart=str(d["chart"]),
                   photo=str(d["photo"]), made_at=str(d["made_at"]),
                   ccm_de00=None if (de := d.get("ccm_de00")) is None
                   else (float(de[0]), float(de[1])),
                   sensor=None if (s := d.get("sensor")) is None else (int(s[0]), int(s[1])))

    def normalise(self, prophoto: NDArray, exposure: Exposure, lux: float) -> NDArray:
        """Developed linear ProPhoto of a shot at ``exposure`` under ``lux`` -> the scale of the
        white-card-normalised simulation (module docstring)."""
        if lux <= 0:
            raise MeasureSetupError(f"lux {lux} must be positive to compare with the set-up")
        return np.asarray(prophoto) * (self.scale * self.exposure.value / exposure.value
                                       * self.lux / lux)


def setup_from_checker(path: Path, corners: Sequence[Sequence[float]], chart: str,
                       exposure: Exposure, lux: float) -> MeasureSetup:
    """The set-up from a RAW ``path`` of the checker (``chart``, patch-area ``corners`` TL, TR,
    BR, BL in pixels of the full-size developed image) photographed at ``exposure`` under
    ``lux`` at the display (module docstring)."""
    from grassd.calib.ccm import fit_ccm
    from grassd.calib.charts import get_chart
    from grassd.calib.checker_photo import checker_white_balance, virtual_checker
    from grassd.calib.colour_spaces import luminance
    from grassd.calib.exposure import GREY_CARD_Y
    from grassd.calib.raw import develop_raw, raw_sensor

    ref = get_chart(chart)
    sensor = raw_sensor(path)
    wb = checker_white_balance(path, corners, ref)  # a patch clipped high or at black: refused
    patches = develop_raw(path, white_balance=wb).checker_patches(corners)
    grey = float(luminance(patches[ref.grey_index()], "prophoto"))
    if not grey > 0:
        raise MeasureSetupError(f"{path.name}: the checker's grey patch is black; check the "
                                "corners and the exposure")
    k = GREY_CARD_Y / grey
    virtual, s = virtual_checker(ref)
    fit = fit_ccm(virtual, patches * k, "3x3")
    ccm = fit.matrix * s
    return MeasureSetup(white_balance=tuple(float(v) for v in wb), scale=k, exposure=exposure,
                        lux=float(lux), ccm=tuple(tuple(float(x) for x in r) for r in ccm),
                        chart=chart, photo=str(path),
                        made_at=datetime.now(UTC).isoformat(timespec="seconds"),
                        ccm_de00=fit.reported_de00, sensor=sensor)


def load_setup(path: Path) -> MeasureSetup:
    """Read ``setup.json``; :class:`MeasureSetupError` telling how to make one."""
    try:
        return MeasureSetup.from_json(json.loads(path.read_text(encoding="utf-8")))
    except FileNotFoundError:
        raise MeasureSetupError(
            "the measuring camera is not set up: lay the colour checker at the display and run "
            "grassd measure setup --corners 'x,y x,y x,y x,y'") from None
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise MeasureSetupError(f"{path} is unreadable ({exc}); run grassd measure setup "
                                "again") from None


@functools.lru_cache(maxsize=4)
def setup_sensor(setup: MeasureSetup) -> tuple[int, int] | None:
    """The sensor size (width, height in photosites) every shot must have: the set-up's, or
    for a set-up made before it was kept, its photo's (from the header) while that file is
    there; None when neither is known (said once per set-up and process)."""
    from grassd.calib.errors import RawReadError
    from grassd.calib.raw import raw_sensor

    if setup.sensor is not None:
        return setup.sensor
    try:
        return raw_sensor(Path(setup.photo))
    except RawReadError as exc:
        log.warning("the set-up shot's sensor size is unknown (%s): measurement shots are "
                    "checked against the RAW size limit only; run grassd measure setup again",
                    exc)
        return None


def develop_shot(shot: Shot, setup: MeasureSetup, lux: float) -> NDArray[np.float32]:
    """(H, W, 3) float32 linear ProPhoto of a shot, developed half size with the set-up's
    white balance and normalised (:meth:`MeasureSetup.normalise`). A shot whose header
    declares another sensor size than the set-up shot's (:func:`setup_sensor`) is refused
    before a pixel is unpacked (:class:`~grassd.calib.errors.RawSizeError`)."""
    from grassd.calib.raw import develop_raw

    dev = develop_raw(shot.raw_path, white_balance=setup.white_balance, half_size=True,
                      sensor=setup_sensor(setup))
    return setup.normalise(dev.rgb, shot.exposure, lux)


class MeasuringCamera:
    """Shots from an OSC camera (:class:`~grassd.daemon.camera.client.OscClient`) in RAW+
    at a fixed ISO into ``dest``; the exposure is metered by the camera for each shot and read
    back as the capture station reads it
    (:func:`~grassd.daemon.camera.bracket.real_exposure`)."""

    def __init__(self, client: OscClient, dest: Path, iso: int) -> None:
        self.client, self.dest, self.iso = client, dest, iso
        self._metered_s: float | None = None
        self._format: dict[str, str | int] | None = None

    def prepare(self) -> None:
        """Put the camera in still-image capture with RAW+ at its own size (as a bracket does),
        once; :meth:`shoot` does it when not yet done."""
        if self._format is not None:
            return
        self.client.ensure_image_mode()
        size = self.client.get_options("fileFormat").get("fileFormat")
        if not isinstance(size, dict):
            raise MeasureSetupError("the measuring camera's getOptions gave no fileFormat "
                                    "object; it must be an OSC camera taking RAW+")
        self._format = {**size, "type": "raw+"}

    def shoot(self, name: str, ev: float = 0.0) -> Shot:
        """Take one shot named ``name`` (file stem); returns its DNG and exposure. ``ev``:
        0 lets the camera meter (ISO priority); otherwise the shutter is set ``ev`` stops from
        the last metered one (manual exposure), e.g. -2 for a scene the meter overexposes."""
        from grassd.daemon.camera.bracket import SHUTTER_SPEEDS_S, BracketPlan, real_exposure

        self.dest.mkdir(parents=True, exist_ok=True)
        self.prepare()
        if ev == 0.0 or self._metered_s is None:
            options: dict[str, float] = {"exposureProgram": 9}
        else:
            want = self._metered_s * 2.0 ** ev
            options = {"exposureProgram": 1, "shutterSpeed": min(
                SHUTTER_SPEEDS_S, key=lambda t: abs(np.log(t / want)))}
        self.client.set_options(iso=self.iso, whiteBalance="daylight",
                                fileFormat=self._format, **options)
        res = self.client.take_picture()
        if not isinstance(res.get("_dngFileUrl"), str):
            raise MeasureSetupError("the measuring camera gave no DNG (_dngFileUrl) for a RAW+ "
                                    "shot; it must support fileFormat raw+ (e.g. THETA Z1)")
        jpeg = self.client.download(res["fileUrl"], self.dest / f"{name}.jpg")
        raw = self.client.download(res["_dngFileUrl"], self.dest / f"{name}.dng")
        t, iso, f, _ = real_exposure(self.client, res, jpeg, BracketPlan(iso=self.iso))
        jpeg.unlink(missing_ok=True)
        if options["exposureProgram"] == 9:
            self._metered_s = float(t)
        return Shot(raw, Exposure(float(t), float(iso), float(f)))
