"""Calibration runs on a dask.distributed cluster (``[compute] scheduler``).

The daemon needs no renderer of its own when ``[compute] scheduler = "tls://host:8786"`` is
set: every run, whole, is one Dask task (:func:`calibrate_on_worker`) that does on a worker
exactly what :meth:`grassd.daemon.core.calibration.calibrate.Calibrator.run` does here, and answers
with the :class:`~grassd.daemon.core.calibration.result.CalibrationResult` the daemon commits as its
own (report, history, push). The workers have ``grassd[sim]`` (Taichi), CPU or GPU; one started
with ``dask worker tls://host:8786 --nthreads 1`` and the site's TLS files (Taichi uses every
core itself) initialises Taichi on its first task (arch from ``$GRASSD_WORKER_ARCH``: "cpu",
the default, or "gpu"; kernel cache as ``grassd.sim.backend.default_cache_dir``) and keeps its
compiled kernels.

Who may join: the client connects with mutual TLS (:class:`distributed.security.Security`:
the site CA's certificate, this daemon's client certificate and key, ``[compute]
tls_ca_file``, ``tls_cert``, ``tls_key``); a scheduler without TLS is used only with
``allow_insecure = true``, with a warning. What travels there: a
:class:`~grassd.daemon.compute.remote_job.CalibrationJob` (the configuration sections the
simulation reads, the light, the bytes of the bundle's HDRI and checker RAW; never a camera's
credentials or the daemon's paths). What comes back: an answer in the declared form of
:mod:`grassd.daemon.compute.wire` (arrays, numbers, text), which the client takes through
Dask's ``msgpack`` serializer only and checks on arrival (:func:`check_arrival`). What Dask's
protocol still unpickles in the daemon is listed in docs/operating/compute.md. A run there gives
the same result, bit for bit, as a local run on the worker's CPU (the renderer is deterministic
for a seed; the timings in ``seconds`` differ).

When the cluster cannot run it (the scheduler unreachable, no worker for ``worker_wait_s``
seconds, the worker running it died or left, the connection dropped, an answer not in the
declared form) the run raises :class:`~grassd.daemon.core.errors.ComputeUnavailable`: the service
keeps the active table and the bundle, which waits in processing/ and is retried with backoff
(health: degraded, with the reason). Several daemons (a fleet of displays) may share one
scheduler: each run is its own task under its own key.
"""

from __future__ import annotations

import logging
import os
import tempfile
import threading
import time
import uuid
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from grassd.daemon.compute.dask_client import connect, fetch_answer, require_secured
from grassd.daemon.compute.remote_job import CalibrationJob, dumps, loads
from grassd.daemon.compute.wire import (
    ErrorAnswer,
    ResultAnswer,
    answer_of,
    error_answer,
    read_answer,
)
from grassd.daemon.core.calibration.correction import (
    SAVED,
    DisplayCorrection,
    Saved,
    with_correction,
)
from grassd.daemon.core.calibration.result import CENTRE, CalibrationResult
from grassd.daemon.core.config.settings import Config
from grassd.daemon.core.errors import (
    CalibrationRejected,
    ComputeResultRefused,
    ComputeUnavailable,
    RunInterrupted,
)
from grassd.sim.light_input import LightInput

if TYPE_CHECKING:
    from distributed import Client, Future
    from numpy.typing import NDArray

    from grassd.calib.ccm import ColourCorrection
    from grassd.daemon.core.store.manifest import CheckerPhoto

log = logging.getLogger(__name__)

#: seconds between two looks at a running task (stop flag, its worker, progress)
POLL_S = 1.0
#: the worker's Taichi arch: "cpu" (the default) or "gpu"
WORKER_ARCH_ENV = "GRASSD_WORKER_ARCH"
__all__ = ["RemoteCalibrator", "calibrate_on_worker", "check_arrival"]


# --------------------------------------------------------------------------- on the worker

#: one calibration at a time per worker process (the renderers are shared per process)
_worker_lock = threading.Lock()


def calibrate_on_worker(payload: bytes) -> ResultAnswer | ErrorAnswer:
    """The Dask task: unpickle a :class:`CalibrationJob` (from the daemon), initialise Taichi
    once per process and run it in a temporary directory; answers with the result, or with
    what the run raised (a rejected table, bad input), in the declared form of
    :mod:`grassd.daemon.compute.wire`."""
    from grassd.sim import backend

    job = loads(payload)
    with _worker_lock, tempfile.TemporaryDirectory(prefix="grassd-run-") as tmp:
        try:
            backend.init(os.environ.get(WORKER_ARCH_ENV, "cpu"))
            return answer_of(job.run(Path(tmp)))
        except Exception as exc:  # every error travels back as an answer, by its name
            log.info("calibration failed on this worker: %s", exc)
            return error_answer(exc)


# --------------------------------------------------------------------------- in the daemon


def check_arrival(cfg: Config, result: CalibrationResult, where: str,
                  previous_um: NDArray | None = None,
                  previous_tables: Mapping[str, NDArray] | None = None,
                  force: bool = False) -> None:
    """Checks of a result decoded from a worker's answer, before the daemon uses it: the
    granularity asked for, tables of the declared form for the configured controllers only
    (shape, monotone, within 0..green_max_mm, and, unless ``force``, within ``[calibration]
    max_jump_mm`` of the active tables as the run itself checks them), a unit for every
    pixel. Raises :class:`ComputeResultRefused` naming what is wrong."""
    from grassd.daemon.core.calibration.checks import check_table

    def refuse(msg: str) -> ComputeResultRefused:
        return ComputeResultRefused(f"{where} answered a result that {msg}")

    if result.granularity != cfg.tables.granularity:
        raise refuse(f"has granularity {result.granularity!r:.40}, not "
                     f"{cfg.tables.granularity!r}")
    if result.source not in (CENTRE, "viewpoints", "audience"):
        raise refuse(f"names the source {result.source!r:.40}")
    pixels = {c.name: sum(b - a + 1 for a, b in c.pixels) for c in cfg.controllers}
    if unknown := sorted(set(result.controller_tables) - set(pixels)):
        raise refuse(f"has tables for controllers that are not configured: {unknown!r:.200}")
    green_max_mm, jump_mm = cfg.display.green_max_mm, cfg.calibration.max_jump_mm
    try:
        if result.table_um.ndim != 1:
            raise CalibrationRejected("its display table is not one (256,) table")
        check_table(result.table_um, green_max_mm,
                    None if result.controller_tables else previous_um, jump_mm, force,
                    "its display table")
        for name, t in result.controller_tables.items():
            if t.ndim == 2 and len(t) != pixels[name]:
                raise CalibrationRejected(f"its tables for {name} are {len(t)}, for "
                                          f"{pixels[name]} pixels")
            prev = None if previous_tables is None else previous_tables.get(name)
            if prev is not None and np.ndim(prev) != 1 and np.shape(prev) != t.shape:
                prev = None  # as the run: its pixel count changed, the display-wide table
            check_table(t, green_max_mm, prev if prev is not None else previous_um, jump_mm,
                        force, f"its table for {name}")
    except CalibrationRejected as exc:
        raise refuse(str(exc)) from None
    units = len(result.units)
    if result.unit_of_pixel.size and (result.unit_of_pixel.ndim != 1
                                      or result.unit_of_pixel.min() < 0
                                      or result.unit_of_pixel.max() >= max(units, 1)
                                      or result.unit_of_pixel.size > cfg.display.pixel_count):
        raise refuse("maps pixels to units it does not have")


class RemoteCalibrator:
    """:meth:`Calibrator.run <grassd.daemon.core.calibration.calibrate.Calibrator.run>` on the
    Dask cluster of ``cfg.compute.scheduler`` (see the module docstring). Raises
    :class:`ConfigError` when the scheduler is not secured as ``[compute]`` requires (a
    ``--scheduler`` given on the command line is checked here); warns once when it is used
    without TLS."""

    def __init__(self, cfg: Config) -> None:
        if cfg.compute.scheduler is None:
            raise ValueError("RemoteCalibrator needs [compute] scheduler")
        require_secured(cfg.compute, cfg.source)
        self.cfg = cfg
        self.address: str = cfg.compute.scheduler

    def job(self, light: LightInput, checker: CheckerPhoto | None, *,
            previous_um: NDArray | None = None, previous_ccm: ColourCorrection | None = None,
            force: bool = False, previous_tables: Mapping[str, NDArray] | None = None
            ) -> bytes:
        """The pickled :class:`CalibrationJob` of one run (the keyword arguments of
        ``Calibrator.run`` that travel). Raises OSError when a file cannot be read."""
        return dumps(CalibrationJob.of(self.cfg, light, checker, previous_um=previous_um,
                                       previous_ccm=previous_ccm, force=force,
                                       previous_tables=previous_tables))

    def run(self, light: LightInput, *, checker: CheckerPhoto | None = None,
            previous_um: NDArray | None = None, previous_ccm: ColourCorrection | None = None,
            force: bool = False, stop: threading.Event | None = None,
            progress: Callable[[str], None] | None = None,
            previous_tables: Mapping[str, NDArray] | None = None,
            correction: DisplayCorrection | Saved | None = SAVED) -> CalibrationResult:
        """Calibrate for ``light`` on the cluster (arguments as ``Calibrator.run``; ``stop``
        and ``progress`` act here: ``progress`` is called every :data:`POLL_S` seconds while
        the task runs, ``stop`` cancels it; the display's ``correction``, which this state
        directory holds, is applied here). Raises :class:`ComputeUnavailable` when the
        cluster cannot run it or answers out of the declared form, :class:`RunInterrupted`
        when ``stop`` is set, and what the run itself raises (CalibError, SimError,
        CalibrationRejected)."""
        payload = self.job(light, checker, previous_um=previous_um, previous_ccm=previous_ccm,
                           force=force, previous_tables=previous_tables)
        if progress:
            progress(f"connecting to the Dask scheduler at {self.address}")
        client = connect(self.cfg.compute)
        try:
            watch = _Watch(client, self.address, self.cfg.compute.worker_wait_s, stop,
                           progress)
            answer = watch.result(payload)
        finally:
            client.close()
        where = f"Dask worker {watch.worker or '(unknown)'} of {self.address}"
        result = read_answer(answer, CalibrationResult, where)
        check_arrival(self.cfg, result, where, previous_um, previous_tables, force)
        return with_correction(self.cfg, result, correction)


class _Watch:
    """One task on ``client``'s cluster, watched until it has a result (see
    :meth:`RemoteCalibrator.run`)."""

    def __init__(self, client: Client, address: str, worker_wait_s: float,
                 stop: threading.Event | None, progress: Callable[[str], None] | None) -> None:
        self.client, self.address, self.worker_wait_s = client, address, worker_wait_s
        self.stop, self.progress = stop, progress
        self.worker: str | None = None  # the worker seen running the task
        self.no_worker_since: float | None = None
        #: what the watch sleeps on between looks (``stop`` when given: it wakes at once)
        self._sleep = stop if stop is not None else threading.Event()

    def result(self, payload: bytes) -> object:
        """The task's answer, unchecked (see :mod:`grassd.daemon.compute.wire`); see
        :meth:`RemoteCalibrator.run` for what it raises."""
        key = f"grassd-calibrate-{uuid.uuid4().hex}"
        fut = None
        try:
            try:
                fut = self.client.submit(calibrate_on_worker, payload, key=key, pure=False,
                                         retries=0)
                t0 = time.monotonic()
                while fut.status == "pending":
                    if self.stop is not None and self.stop.is_set():
                        raise RunInterrupted("calibration stopped (daemon shutting down)")
                    self._look(key, time.monotonic() - t0)
                    self._sleep.wait(POLL_S)
                if fut.status not in ("finished", "error"):  # cancelled, lost
                    raise ComputeUnavailable(
                        f"the Dask scheduler at {self.address} dropped the run ({fut.status}: "
                        "restarted, or its worker's data was lost)")
            except (OSError, ValueError) as exc:  # the connection dropped (CommClosedError)
                raise ComputeUnavailable(
                    f"lost the Dask scheduler at {self.address} during the run ({exc})") from None
            return self._outcome(fut)
        finally:
            if fut is not None and fut.status == "pending":
                try:  # nobody waits for it any more: free its worker
                    fut.cancel()
                except (OSError, ValueError, RuntimeError) as exc:
                    log.debug("cannot cancel the Dask task %s: %s", key, exc)

    def _outcome(self, fut: Future) -> object:
        """The finished task's answer as Dask's ``msgpack`` serializer read it (the run's own
        errors are part of the answer); see :func:`~grassd.daemon.compute.dask_client.
        fetch_answer` for what it raises."""
        answer, self.worker = fetch_answer(self.client, fut, self.address, self.worker)
        return answer

    def _look(self, key: str, elapsed_s: float) -> None:
        """Check the task's worker and the cluster's workers; report progress. Raises
        :class:`ComputeUnavailable` when the worker running the task left, or when the
        cluster has had no worker for ``worker_wait_s`` seconds."""
        workers = set(self.client.scheduler_info(n_workers=-1).get("workers", {}))
        now = time.monotonic()
        if not workers:
            self.no_worker_since = self.no_worker_since or now
            if now - self.no_worker_since >= self.worker_wait_s:
                lost = f"; its worker {self.worker} died" if self.worker else ""
                raise ComputeUnavailable(
                    f"the Dask scheduler at {self.address} has had no worker for "
                    f"{now - self.no_worker_since:.0f} s{lost}: start one there "
                    "(dask worker <scheduler address>, with grassd[sim])")
        else:
            self.no_worker_since = None
        if self.worker is not None and self.worker not in workers:
            raise ComputeUnavailable(f"Dask worker {self.worker} died or left during the run "
                                     f"(scheduler {self.address})")
        if self.worker is None:
            running = [w for w, keys in self.client.processing().items() if key in keys]
            self.worker = running[0] if running else None
        if self.progress:
            where = f"on Dask worker {self.worker}" if self.worker else "queued"
            self.progress(f"calibrating on the Dask cluster at {self.address}: {where}, "
                          f"{elapsed_s:.0f} s")
