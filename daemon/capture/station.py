"""The capture station: bracket -> merged EXR + lux -> a bundle in the inbox, once or on a
schedule (``grassd capture``, the ``[capture]`` section
:mod:`grassd.daemon.camera.config`, the simulated camera
:mod:`grassd.rigs.simulated_camera`).

One capture (:meth:`Station.capture_once`):

1. ``/osc/info`` (model, serial, firmware), then the bracket
   (:mod:`grassd.daemon.camera.bracket`; the camera:
   :mod:`grassd.daemon.camera.client`) into a private work directory under
   ``state_dir/capture/work``;
2. the camera response: the cached one of this camera (``state_dir/capture/response/<camera
   key>-iso<ISO>-<white balance>.json``) while younger than ``response_max_age_days``, else
   recovered from this bracket (:func:`grassd.calib.hdr_merge.recover_response`) and cached;
3. the merge (:func:`grassd.calib.hdr_merge.merge_ldr`) into a scene-linear EXR; a sun that
   is still clipped in the shortest exposure is flagged (``capture.sun_clipped``) so that the
   daemon restores it from the lux reading (``sun_from_hdri``, :func:`grassd.sim.sun.split_sun`);
4. lux from ``[light.modbus]`` right after the bracket (or ``lux`` given); with a shaded
   sensor, ambient = shaded and sun = unshaded - shaded;
5. the bundle: a directory written under a hidden name in the inbox (the inbox ignores
   names starting with ``.``), every file fsynced, manifest last, then renamed to its final
   name in one ``rename(2)``. A failure at any step leaves nothing in the inbox.

Failures are typed (:class:`~grassd.daemon.core.errors.CaptureError` and its subclasses,
:class:`~grassd.daemon.core.errors.LuxSensorError`);
:meth:`Station.capture` retries them ``retries`` times with doubling backoff. It holds
``state_dir/capture/camera.lock`` (an flock,
:class:`~grassd.daemon.core.runtime.statelock.StateLock`) meanwhile: a second capture into the same
state directory (``grassd capture`` while the daemon captures) fails at once with
:class:`~grassd.daemon.core.errors.CameraBusy` naming the holder, instead of driving the camera
between the other's shots and removing its work files as leftovers. :class:`CaptureLoop` runs
captures every ``interval_s`` in its own thread, so a capture never blocks or delays a calibration
(the daemon's main thread only sees the finished bundle).
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import logging
import os
import shutil
import threading
import time
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING, NotRequired, TypedDict

import numpy as np
import tomli_w

from grassd.calib.errors import (
    BracketBlackError,
    BracketClippedError,
    HdrMergeError,
    RawReadError,
)
from grassd.daemon.camera.bracket import BracketPlan, Shot, capture_bracket, load_codes
from grassd.daemon.camera.client import CameraInfo, OscClient
from grassd.daemon.camera.config import CaptureConfig
from grassd.daemon.core.config.settings import Config, ModbusConfig
from grassd.daemon.core.errors import BracketUnusable, CameraBusy, CaptureError, LuxSensorError
from grassd.daemon.core.runtime.statelock import StateLock
from grassd.daemon.core.store.atomic import (
    atomic_write_json,
    atomic_write_text,
    fsync_dir,
    fsync_file,
)
from grassd.daemon.core.store.layout import CAMERA_LOCK
from grassd.daemon.core.timestamps import utc_iso

if TYPE_CHECKING:
    from grassd.calib.hdr_merge import MergeResult

log = logging.getLogger(__name__)

#: Name of the merged panorama inside a capture bundle.
HDRI_NAME = "sky.exr"
#: Lock file under ``state_dir/capture`` held while a station captures.


class CaptureTable(TypedDict):
    """The ``[capture]`` table of a bundle's manifest: the camera, the bracket (exposures in s,
    as requested and as taken), how it was merged, its clipped and black fractions (0-1), and
    whether the sun clipped even in the shortest shot."""

    camera_url: str
    camera_model: str
    camera_manufacturer: str
    camera_serial: str
    camera_firmware: str
    exposures_s: list[float]
    requested_s: list[float]
    exposure_source: list[str]
    iso: int
    white_balance: str
    file_format: str
    f_number: float
    merge_method: str
    response: str
    shots_used: int
    clipped_fraction: float
    black_fraction: float
    sun_clipped: bool
    lux_source: str


class BundleManifest(TypedDict):
    """A captured bundle's manifest as written: the light's time (ISO 8601), the panorama's
    file name, ambient and sun lux [lx], and the ``[capture]`` table."""

    timestamp: str
    hdri: str
    ambient_lux: float
    sun_lux: NotRequired[float]
    capture: CaptureTable


class CaptureSummary(TypedDict):
    """The capture loop under ``capture`` in ``grassd status``: its camera and interval (s),
    the captures made, the last attempt's and success's times (epoch s), the last bundle's
    name and error, and the time to the next capture (s)."""

    camera: str
    interval_s: float
    captures: int
    last_at: float | None
    last_success_at: float | None
    last_bundle: str | None
    last_error: str | None
    next_in_s: float | None


@dataclass(frozen=True)
class CaptureResult:
    """A written bundle: its directory in the inbox and its manifest (as written)."""

    bundle: Path
    manifest: BundleManifest


def manifest_toml(manifest: BundleManifest) -> str:
    """TOML text of a bundle manifest: top-level keys, then the ``[capture]`` table."""
    return tomli_w.dumps(manifest)


def clipped_sun(clipped: np.ndarray) -> bool:
    """True when texels clipped even in the shortest exposure (``clipped``, (H, W) bool) form a
    compact region above the horizon: a sun whose radiance in the map is only a lower bound.
    Compact: an 8-connected component whose solid angle is at most
    :data:`grassd.sim.sun.MAX_SUN_SOLID_ANGLE_SR` (a window or white wall is larger)."""
    from scipy import ndimage

    from grassd.sim.lighting import texel_solid_angles
    from grassd.sim.sun import MAX_SUN_SOLID_ANGLE_SR

    h, w = clipped.shape
    if not clipped[: h // 2].any():
        return False
    labels, n = ndimage.label(clipped, structure=np.ones((3, 3), bool))
    omega = np.broadcast_to(texel_solid_angles(h, w)[:, None], (h, w))
    rows = np.arange(h)[:, None] * np.ones((1, w))
    index = np.arange(1, n + 1)
    area = ndimage.sum_labels(omega, labels, index)
    centre_row = ndimage.mean(rows, labels, index)
    return bool(((area <= MAX_SUN_SOLID_ANGLE_SR) & (centre_row < h / 2)).any())


class Station:
    """Makes bundles from the camera of ``cfg`` into ``inbox``; ``modbus`` is the lux sensor
    (None: the bundle carries lux only when given to :meth:`capture_once`)."""

    def __init__(self, cfg: CaptureConfig, inbox: Path, state_dir: Path,
                 modbus: ModbusConfig | None = None,
                 site: tuple[float, float] | None = None) -> None:
        self.cfg = cfg
        self.site = site  # (latitude, longitude) in degrees, east +: see sun_share
        self.inbox = Path(inbox)
        self.root = Path(state_dir) / "capture"
        self.modbus = modbus
        self.client = OscClient.from_config(cfg)
        self.captures = 0
        self.last_error: str | None = None
        self._cleaned = False

    def _clean_leftovers(self) -> None:
        """Remove what a capture cut short by a crash or power cut left behind: hidden
        partial bundles in the inbox (the inbox ignores them) and work directories. Done at
        this station's first capture, not when it is made: a station replacing another (a
        reload) is made while the other may still be capturing into the same places."""
        self._cleaned = True
        with contextlib.suppress(OSError):
            for p in self.inbox.glob(".capture-*.partial"):
                log.warning("removing the partial bundle %s of an interrupted capture", p)
                shutil.rmtree(p, ignore_errors=True)
        shutil.rmtree(self.root / "work", ignore_errors=True)

    def plan(self) -> BracketPlan:
        """The bracket ``[capture]`` asks for."""
        c = self.cfg
        return BracketPlan(shots=c.shots, ev_step=c.ev_step, iso=c.iso, aperture=c.aperture,
                           white_balance=c.white_balance, centre_shutter_s=c.shutter_s or None,
                           max_shutter_s=c.max_shutter_s, file_format=c.file_format)

    # ------------------------------------------------------------------ response cache
    def _response_path(self, info: CameraInfo) -> Path:
        wb = "".join(ch if ch.isalnum() else "_" for ch in self.cfg.white_balance)
        return self.root / "response" / f"{info.key}-iso{self.cfg.iso}-{wb}.json"

    def _cached_response(self, path: Path) -> tuple[np.ndarray, str] | None:
        try:
            data = json.loads(path.read_text())
            resp = np.asarray(data["response"], dtype=np.float64)
            age_days = (time.time() - float(data["recovered_at"])) / 86400.0
        except (OSError, ValueError, KeyError, TypeError):
            return None
        if resp.shape != (256, 3) or age_days > self.cfg.response_max_age_days:
            return None
        return resp, str(data.get("recovered_at_iso", ""))

    def response(self, info: CameraInfo, codes: list[np.ndarray],
                 exposures: list[float]) -> tuple[np.ndarray, str]:
        """The camera response for this bracket and how it was obtained (step 2)."""
        from grassd.calib.hdr_merge import recover_response

        path = self._response_path(info)
        cached = self._cached_response(path)
        if cached is not None:
            return cached[0], f"cached (recovered {cached[1]})"
        resp = recover_response(codes, exposures)
        now = time.time()
        atomic_write_json(path, {"camera": info.key, "iso": self.cfg.iso,
                                 "white_balance": self.cfg.white_balance,
                                 "method": "debevec1997", "recovered_at": now,
                                 "recovered_at_iso": utc_iso(now),
                                 "response": resp.tolist()})
        return resp, "recovered from this bracket"

    def merge(self, info: CameraInfo, shots: list[Shot], exposures: list[float]
              ) -> tuple[MergeResult, str]:
        """The merged bracket and how its linearisation was obtained (step 3): RAW+ shots
        linearly through rawpy, JPEG shots with the camera response."""
        from grassd.calib.hdr_merge import merge_ldr, merge_linear

        if all(s.raw_path is not None for s in shots):
            from grassd.calib.raw_bracket import develop_bracket

            images = develop_bracket([s.raw_path for s in shots])
            return merge_linear(images, exposures), "linear RAW (rawpy)"
        codes = load_codes(shots)
        resp, how = self.response(info, codes, exposures)
        return merge_ldr(codes, exposures, resp), how

    # ------------------------------------------------------------------ lux
    def read_lux(self) -> tuple[float, float | None, str]:
        """(ambient lux, sun lux or None, source) from the sensor(s) (step 4)."""
        from grassd.daemon.core.hardware.luxsensor import read_lux

        if self.modbus is None:
            raise LuxSensorError("no lux: [light.modbus] names no sensor and no --lux was "
                                 "given")
        total = read_lux(self.modbus)
        if not self.cfg.shaded_unit:
            return total, None, "modbus"
        shaded_cfg = dataclasses.replace(self.modbus, unit=self.cfg.shaded_unit,
                                         port=self.cfg.shaded_port or self.modbus.port)
        shaded = read_lux(shaded_cfg)
        return shaded, max(total - shaded, 0.0), "modbus (shaded + unshaded)"

    def sun_share(self, sun_lux: float | None, when: datetime) -> float | None:
        """The sun lux [lx] a bundle records from two sensors' difference at ``when``: as
        read while the sun is above the horizon at the site; 0 while it is below (then the
        difference is the sensors' mismatch, and ingest refuses sun lux from below the
        horizon). Unchanged without a site or a second sensor."""
        if not sun_lux or self.site is None:
            return sun_lux
        from grassd.sim.sun import sun_position

        elevation = sun_position(*self.site, when)[1]
        if elevation > 0.0:
            return sun_lux
        log.info("capture: the sensors differ by %.1f lx with the sun %.1f deg below the "
                 "horizon: recorded as no sun", sun_lux, -elevation)
        return 0.0

    # ------------------------------------------------------------------ one capture
    def capture_once(self, lux: float | None = None) -> CaptureResult:
        """One capture attempt (module docstring); raises a typed error, leaving no bundle."""
        from grassd.calib.hdr_merge import relative_exposure
        from grassd.sim.hdri import write_exr
        started = datetime.now(UTC)
        stamp = started.strftime("%Y%m%dT%H%M%S") + f"{started.microsecond // 1000:03d}Z"
        work = self.root / "work" / stamp
        name = f"capture-{stamp}"
        partial = self.inbox / f".{name}.partial"
        try:
            info = self.client.info()
            self.client.state()
            shots = capture_bracket(self.client, self.plan(), work)
            if lux is None:
                ambient, sun_lux, lux_source = self.read_lux()
                sun_lux = self.sun_share(sun_lux, started)
            else:
                ambient, sun_lux, lux_source = float(lux), None, "--lux"
            exposures = [relative_exposure(s.exposure_s, s.iso, s.f_number) for s in shots]
            try:
                merged, how = self.merge(info, shots, exposures)
            except (BracketClippedError, BracketBlackError) as exc:
                raise BracketUnusable(f"bracket from {self.cfg.camera} unusable: {exc}") from None
            except (HdrMergeError, RawReadError) as exc:
                raise BracketUnusable(f"bracket from {self.cfg.camera} cannot be merged: "
                                      f"{exc}") from None
            sun_clipped = clipped_sun(merged.clipped)
            capture: CaptureTable = {
                "camera_url": self.cfg.camera, "camera_model": info.model,
                "camera_manufacturer": info.manufacturer, "camera_serial": info.serial,
                "camera_firmware": info.firmware,
                "exposures_s": [s.exposure_s for s in shots],
                "requested_s": [s.requested_s for s in shots],
                "exposure_source": sorted({s.source for s in shots}),
                "iso": self.cfg.iso, "white_balance": self.cfg.white_balance,
                "file_format": self.cfg.file_format,
                "f_number": shots[0].f_number,
                "merge_method": merged.method, "response": how,
                "shots_used": merged.shots_used,
                "clipped_fraction": round(merged.clipped_fraction, 6),
                "black_fraction": round(merged.black_fraction, 6),
                "sun_clipped": sun_clipped, "lux_source": lux_source,
            }
            manifest = BundleManifest(timestamp=started.isoformat(timespec="seconds"),
                                      hdri=HDRI_NAME, ambient_lux=round(ambient, 3),
                                      capture=capture)
            if sun_lux is not None:
                manifest["sun_lux"] = round(sun_lux, 3)
            partial.mkdir(parents=True)
            write_exr(partial / HDRI_NAME, merged.radiance)
            fsync_file(partial / HDRI_NAME)  # write_exr renames but does not fsync
            atomic_write_text(partial / "manifest.toml", manifest_toml(manifest))
            fsync_dir(partial)
            final = self.inbox / name
            os.rename(partial, final)
            fsync_dir(self.inbox)
        except BaseException:
            shutil.rmtree(partial, ignore_errors=True)
            raise
        finally:
            shutil.rmtree(work, ignore_errors=True)
        self.captures += 1
        log.info("capture %s: %d shots %.3g..%.3g s, response %s, clipped %.2f%%%s -> %s",
                 name, len(shots), shots[0].exposure_s, shots[-1].exposure_s, how,
                 100 * merged.clipped_fraction, ", sun clipped" if sun_clipped else "", final)
        return CaptureResult(final, manifest)

    def capture(self, lux: float | None = None, stop: threading.Event | None = None,
                sleep=time.sleep) -> CaptureResult:
        """:meth:`capture_once`, retried ``retries`` times after a typed failure with backoff
        ``retry_s``, doubling; raises the last error. ``stop`` ends the waiting early.
        :class:`CameraBusy` when another capture into this state directory is running."""
        lock = StateLock(self.root, name=CAMERA_LOCK)
        if not lock.try_acquire():
            raise CameraBusy(f"camera {self.cfg.camera} is busy: "
                             f"{lock.holder_name('another grassd process')} is capturing into "
                             f"{self.root.parent}; try again when it has finished")
        try:
            return self._capture_locked(lux, stop, sleep)
        finally:
            lock.release()

    def _capture_locked(self, lux: float | None, stop: threading.Event | None,
                        sleep) -> CaptureResult:
        if not self._cleaned:
            self._clean_leftovers()
        delay = self.cfg.retry_s
        for attempt in range(self.cfg.retries + 1):
            try:
                out = self.capture_once(lux)
                self.last_error = None
                return out
            except (CaptureError, LuxSensorError, OSError) as exc:
                self.last_error = str(exc)
                if attempt == self.cfg.retries or (stop is not None and stop.is_set()):
                    raise
                log.warning("capture failed (attempt %d of %d), again in %g s: %s",
                            attempt + 1, self.cfg.retries + 1, delay, exc)
                if stop is not None:
                    if stop.wait(delay):
                        raise
                else:
                    sleep(delay)
                delay *= 2
        raise AssertionError("unreachable")


class CaptureLoop:
    """Captures every ``cfg.interval_s`` seconds in a daemon thread until :meth:`stop`; the
    first capture right after :meth:`start` (after the thread of ``after``, a loop being
    replaced, has finished its capture: one camera, one client at a time). Failures are
    logged and kept in :attr:`last_error`; the loop goes on with the next interval."""

    def __init__(self, station: Station) -> None:
        self.station = station
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.last_bundle: Path | None = None
        self.last_error: str | None = None
        self.last_at: float | None = None
        #: when a capture last delivered a bundle (epoch s; None: not yet)
        self.last_success_at: float | None = None
        self.next_at: float | None = None

    def start(self, after: CaptureLoop | None = None) -> CaptureLoop:
        """Start the capture thread."""
        before = None if after is None else after._thread
        self._thread = threading.Thread(target=self._run, args=(before,), name="capture",
                                        daemon=True)
        self._thread.start()
        log.info("capture station: %s every %g s", self.station.cfg.camera,
                 self.station.cfg.interval_s)
        return self

    def _run(self, before: threading.Thread | None) -> None:
        if before is not None:
            before.join()
        while not self._stop.is_set():
            begun = time.monotonic()
            try:
                self.last_bundle = self.station.capture(stop=self._stop).bundle
                self.last_error = None
                self.last_success_at = time.time()
            except (CaptureError, LuxSensorError, OSError) as exc:
                self.last_error = str(exc)
                log.error("capture failed after %d attempt(s): %s (next in %g s)",
                          self.station.cfg.retries + 1, exc, self.station.cfg.interval_s)
            except Exception as exc:  # noqa: BLE001 - never let the thread die silently
                self.last_error = f"{type(exc).__name__}: {exc}"
                log.exception("capture crashed; the loop goes on")
            self.last_at = time.time()
            wait = max(self.station.cfg.interval_s - (time.monotonic() - begun), 0.0)
            self.next_at = time.time() + wait
            self._stop.wait(wait)

    def stop(self, timeout_s: float | None = 30.0) -> None:
        """Ask the loop to stop after the capture in progress (if any); wait up to
        ``timeout_s`` seconds for it (None: do not wait)."""
        self._stop.set()
        if self._thread is not None and timeout_s is not None:
            with contextlib.suppress(RuntimeError):
                self._thread.join(timeout_s)

    def summary(self) -> CaptureSummary:
        """For ``grassd status``: camera, interval, captures made, last bundle and error, and
        when the next capture is due (s)."""
        return {"camera": self.station.cfg.camera, "interval_s": self.station.cfg.interval_s,
                "captures": self.station.captures, "last_at": self.last_at,
                "last_success_at": self.last_success_at,
                "last_bundle": None if self.last_bundle is None else self.last_bundle.name,
                "last_error": self.last_error,
                "next_in_s": None if self.next_at is None else max(self.next_at - time.time(),
                                                                   0.0)}


def start_capture_loop(cfg: Config, after: CaptureLoop | None = None) -> CaptureLoop:
    """The daemon's capture thread for ``cfg`` ([capture], the inbox, [light.modbus]),
    starting once ``after`` (a loop it replaces) has finished."""
    assert cfg.capture is not None
    return CaptureLoop(Station(cfg.capture, cfg.light.inbox, cfg.state_dir, cfg.light.modbus,
                               site=(cfg.site.latitude, cfg.site.longitude))).start(after)
