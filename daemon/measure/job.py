"""A measurement as the daemon runs it: camera, light, the run, and what is kept afterwards.

:func:`measure_with` takes a :class:`~grassd.daemon.core.runtime.service.Service` (its config,
fleet, history, calibrator, lux sensor, stop event and progress) and:

* opens the measuring camera of ``[measure] camera`` (the capture station's, holding its lock,
  or a second one) and reads the camera's set-up (``measure/setup.json``);
* takes the light a scheduled run would (the last bundle's panorama, the lux now);
* runs :func:`grassd.daemon.measure.run.run_measurement`;
* when the measurement is accepted (its photos are evidence and it made the display more
  uniform): saves the correction
  (``measure/correction.json``, atomically), then commits the corrected tables as a run whose
  trigger is "measure" and pushes them; every later run includes the correction;
* whatever happened, writes the measurement's report (``measure/<id>.json`` and ``.html``) with
  its status ("ok"; "refused" when its photos are not evidence,
  :mod:`grassd.daemon.measure.evidence`; "failed", "interrupted") and error;
* keeps the photos of the newest ``[measure] keep_photos`` measurements
  (:func:`grassd.daemon.core.runtime.retention.prune_measure_photos`).

A measurement that fails leaves the correction and the active tables as they were.
"""

from __future__ import annotations

import logging
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING

from grassd.daemon.core.errors import USER_ERRORS, DaemonError, RunInterrupted

if TYPE_CHECKING:
    from grassd.daemon.camera.client import OscClient
    from grassd.daemon.core.config.settings import Config
    from grassd.daemon.core.runtime.service import Service
    from grassd.daemon.measure.report import MeasurementReport

log = logging.getLogger(__name__)


def measuring_camera(cfg: Config) -> tuple[OscClient, Path | None]:
    """(OSC client of ``[measure] camera``, the camera lock's directory when it is the capture
    station's camera, else None)."""
    from dataclasses import replace

    from grassd.daemon.camera.client import OscClient
    from grassd.daemon.camera.config import CaptureConfig

    mc = cfg.measure
    if mc.camera == "capture":
        return OscClient.from_config(cfg.capture), Path(cfg.state_dir) / "capture"
    base = cfg.capture if cfg.capture is not None else CaptureConfig(camera=mc.camera)
    return OscClient.from_config(replace(base, camera=mc.camera, username=mc.username,
                                         password=mc.password)), None


def measure_with(svc: Service, trigger: str = "request") -> MeasurementReport:
    """One measurement by the service ``svc`` (module docstring); returns its report."""
    from grassd.daemon.core.calibration.calibrate import init_backend
    from grassd.daemon.core.runtime.retention import prune_measure_photos
    from grassd.daemon.core.runtime.scheduled import scheduled_input
    from grassd.daemon.core.runtime.statelock import StateLock
    from grassd.daemon.core.store.atomic import atomic_write_json
    from grassd.daemon.core.store.layout import CAMERA_LOCK, StateLayout
    from grassd.daemon.measure.camera_chain import load_setup
    from grassd.daemon.measure.report import write_report
    from grassd.daemon.measure.run import MeasureContext, measurement_id, run_measurement

    cfg = svc.cfg
    layout = StateLayout(cfg.state_dir)
    started = datetime.now(UTC)
    report: MeasurementReport = {"measurement": measurement_id(started), "trigger": trigger,
                                 "started_at": started.isoformat(timespec="seconds")}
    lock = None
    try:
        if cfg.measure is None:
            raise DaemonError("no [measure] section: configure the measuring camera first")
        # the pixel models are recorded here, even when [compute] sends the runs to a Dask
        # cluster: this computer needs Taichi to measure (RendererMissing says so)
        init_backend(cfg)
        setup = load_setup(layout.measure_setup)
        camera, lock_dir = measuring_camera(cfg)
        camera.info()  # reachable before the display is taken over
        if lock_dir is not None:
            lock = StateLock(lock_dir, name=CAMERA_LOCK)
            lock_dir.mkdir(parents=True, exist_ok=True)
            if not lock.try_acquire():
                raise DaemonError(f"the capture station's camera is busy "
                                  f"({lock.holder_name('another grassd process')}); measure "
                                  "again when its capture has finished")
        sensor_first = cfg.light.lux == "modbus" and svc.sensor is not None
        inp = scheduled_input(svc.history, svc.inbox, sensor_first, svc._resolve_lux)
        lux_now = ((lambda: svc._resolve_lux(None)[0]) if sensor_first
                   else (lambda: float(inp.lux)))
        ctx = MeasureContext(cfg=cfg, fleet=svc.fleet, calibrator=svc.calibrator,
                             light=inp.light, lux=lux_now, camera=camera, setup=setup,
                             dest=layout.measure, stop=svc.stop_event.is_set,
                             progress=svc._progress)
        outcome = run_measurement(ctx)
        report = {**report, **outcome.report, "trigger": trigger}
        if outcome.accepted is not None:
            correction, corrected = outcome.accepted
            atomic_write_json(layout.correction, correction.to_json())
            run_id = svc.history.start_run("measure", input_hashes={"measurement":
                                                                    report["measurement"]},
                                           lux=inp.lux, lux_source=inp.lux_source,
                                           light_at=inp.light_at)
            out = svc._commit(run_id, corrected)
            report["tables"].update({"run_id": run_id, "status": out.status.value,
                                     "pushed": [c.ok for c in out.controllers]})
        else:
            report["tables"].update({"run_id": None, "status": "kept the last tables: "
                                     + report.get("error", "the correction was refused")})
    except RunInterrupted as exc:
        report.update(status="interrupted", error=str(exc))
    except (*USER_ERRORS, OSError) as exc:  # the display, camera, light or controllers
        report.update(status="failed", error=str(exc))
        log.warning("measurement failed: %s", exc)
    except Exception as exc:  # a bug must not kill the service
        log.exception("measurement failed")
        report.update(status="failed", error=f"internal error: {exc!r}")
    finally:
        if lock is not None:
            lock.release()
        report["finished_at"] = datetime.now(UTC).isoformat(timespec="seconds")
        try:
            report["report"] = str(write_report(layout, report))
        except OSError as exc:
            log.error("measurement report not written: %s", exc)
        if cfg.measure is not None:
            prune_measure_photos(layout.measure, cfg.measure.keep_photos)
    return report
