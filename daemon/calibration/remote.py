"""Calibration runs on a dask.distributed cluster (``[compute] scheduler``).

The daemon needs no renderer of its own when ``[compute] scheduler = "tcp://host:8786"`` is
set: every run, whole, is one Dask task (:func:`calibrate_on_worker`) that does on a worker
exactly what :meth:`grassd.daemon.calibration.calibrate.Calibrator.run` does here, and returns
the :class:`~grassd.daemon.calibration.result.CalibrationResult` the daemon commits as its own
(report, history, push). The workers have ``grassd[sim]`` (Taichi), CPU or GPU; one started
with ``dask worker tcp://host:8786 --nthreads 1`` (Taichi uses every core itself) initialises
Taichi on its first task (arch from ``$GRASSD_WORKER_ARCH``: "cpu", the default, or "gpu";
kernel cache as ``grassd.sim.backend.default_cache_dir``) and keeps its compiled kernels.

What travels: the configuration, the light (with the ambient lux already resolved) and the
bytes of the bundle's HDRI and checker RAW, so no worker needs the daemon's files; the worker
writes them to a temporary directory under their own names and runs on them. A run there
gives the same result, bit for bit, as a local run on the worker's CPU (the renderer is
deterministic for a seed; the timings in ``seconds`` differ).

When the cluster cannot run it (the scheduler unreachable, no worker for ``worker_wait_s``
seconds, the worker running it died or left, the connection dropped) the run raises
:class:`~grassd.daemon.errors.ComputeUnavailable`: the service keeps the active table and the
bundle, which waits in processing/ and is retried with backoff (health: degraded, with the
reason). Several daemons (a fleet of displays) may share one scheduler: each run is its own
task under its own key.
"""

from __future__ import annotations

import copyreg
import io
import logging
import os
import pickle
import tempfile
import threading
import time
import types
import uuid
from collections.abc import Callable, Mapping
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from grassd.daemon.calibration.correction import SAVED, with_correction
from grassd.daemon.config.settings import Config
from grassd.daemon.errors import ComputeUnavailable, RunInterrupted
from grassd.sim.light_input import LightInput

if TYPE_CHECKING:
    from numpy.typing import NDArray

    from grassd.daemon.calibration.result import CalibrationResult
    from grassd.daemon.store.manifest import CheckerPhoto

log = logging.getLogger(__name__)

#: seconds between two looks at a running task (stop flag, its worker, progress)
POLL_S = 1.0
#: the worker's Taichi arch: "cpu" (the default) or "gpu"
WORKER_ARCH_ENV = "GRASSD_WORKER_ARCH"

__all__ = ["RemoteCalibrator", "calibrate_on_worker", "calibrator_for", "dumps", "loads"]


# --------------------------------------------------------------------------- serialisation


def _mapping_proxy(d: dict[str, Any]) -> Mapping[str, Any]:
    """A read-only view of ``d`` (how a pickled ``types.MappingProxyType`` comes back)."""
    return types.MappingProxyType(d)


def _reduce_mapping_proxy(m: Mapping[str, Any]) -> tuple[Any, tuple[dict[str, Any]]]:
    return _mapping_proxy, (dict(m),)


def dumps(obj: Any) -> bytes:
    """Pickle ``obj`` (a configuration holds read-only mappings, which plain pickle refuses:
    they travel as dicts and come back read-only)."""
    buf = io.BytesIO()
    p = pickle.Pickler(buf, protocol=pickle.HIGHEST_PROTOCOL)
    p.dispatch_table = {**copyreg.dispatch_table, types.MappingProxyType: _reduce_mapping_proxy}
    p.dump(obj)
    return buf.getvalue()


def loads(data: bytes) -> Any:
    """The object :func:`dumps` pickled."""
    return pickle.loads(data)


# --------------------------------------------------------------------------- on the worker

#: one calibration at a time per worker process (the renderers are shared per process)
_worker_lock = threading.Lock()


def calibrate_on_worker(payload: bytes) -> bytes:
    """The Dask task: unpickle a job of :meth:`RemoteCalibrator.job`, write its HDRI and
    checker RAW into a temporary directory, initialise Taichi once per process and run
    :meth:`Calibrator.run <grassd.daemon.calibration.calibrate.Calibrator.run>` on them;
    returns the pickled :class:`CalibrationResult`. Errors (a rejected table, bad input)
    travel back to the daemon as they are."""
    from grassd.daemon.calibration.calibrate import Calibrator
    from grassd.sim import backend

    job = loads(payload)
    with _worker_lock, tempfile.TemporaryDirectory(prefix="grassd-run-") as tmp:
        backend.init(os.environ.get(WORKER_ARCH_ENV, "cpu"))
        light: LightInput = job["light"]
        hdri = Path(tmp) / light.hdri.name
        hdri.write_bytes(job["hdri"])
        light = replace(light, hdri=hdri)
        checker = job["checker"]
        if checker is not None:
            raw = Path(tmp) / checker.raw.name
            raw.write_bytes(job["checker_raw"])
            checker = replace(checker, raw=raw)
        result = Calibrator(job["cfg"]).run(light, checker=checker, **job["kwargs"])
    return dumps(result)


# --------------------------------------------------------------------------- in the daemon


def calibrator_for(cfg: Config) -> Any:
    """What runs ``cfg``'s calibrations: a :class:`RemoteCalibrator` with ``[compute]
    scheduler``, else a local :class:`~grassd.daemon.calibration.calibrate.Calibrator`
    (Taichi here). Both have the same ``run``."""
    if cfg.compute.scheduler is not None:
        return RemoteCalibrator(cfg)
    from grassd.daemon.calibration.calibrate import Calibrator

    return Calibrator(cfg)


class RemoteCalibrator:
    """:meth:`Calibrator.run <grassd.daemon.calibration.calibrate.Calibrator.run>` on the
    Dask cluster of ``cfg.compute.scheduler`` (see the module docstring)."""

    def __init__(self, cfg: Config) -> None:
        if cfg.compute.scheduler is None:
            raise ValueError("RemoteCalibrator needs [compute] scheduler")
        self.cfg = cfg
        self.address: str = cfg.compute.scheduler

    def job(self, light: LightInput, checker: CheckerPhoto | None,
            **kwargs: Any) -> bytes:
        """The pickled job of one run: configuration, light, the HDRI's and the checker RAW's
        bytes, and the keyword arguments of ``Calibrator.run`` that travel (``previous_um``,
        ``previous_ccm``, ``force``, ``previous_tables``). Raises OSError when a file cannot
        be read."""
        return dumps({"cfg": self.cfg, "light": light, "hdri": Path(light.hdri).read_bytes(),
                      "checker": checker,
                      "checker_raw": None if checker is None else Path(checker.raw).read_bytes(),
                      "kwargs": kwargs})

    def run(self, light: LightInput, *, checker: CheckerPhoto | None = None,
            previous_um: NDArray | None = None, previous_ccm: NDArray | None = None,
            force: bool = False, stop: threading.Event | None = None,
            progress: Callable[[str], None] | None = None,
            previous_tables: Mapping[str, NDArray] | None = None,
            correction: Any = SAVED) -> CalibrationResult:
        """Calibrate for ``light`` on the cluster (arguments as ``Calibrator.run``; ``stop``
        and ``progress`` act here: ``progress`` is called every :data:`POLL_S` seconds while
        the task runs, ``stop`` cancels it; the display's ``correction``, which this state
        directory holds, is applied here). Raises :class:`ComputeUnavailable` when the
        cluster cannot run it, :class:`RunInterrupted` when ``stop`` is set, and what the run
        itself raises (CalibError, SimError, CalibrationRejected)."""
        payload = self.job(light, checker, previous_um=previous_um, previous_ccm=previous_ccm,
                           force=force, previous_tables=previous_tables, correction=None)
        try:
            from distributed import Client
        except ImportError:
            raise ComputeUnavailable(
                "[compute] scheduler needs dask.distributed here: pip install "
                "'dask[distributed]'") from None
        if progress:
            progress(f"connecting to the Dask scheduler at {self.address}")
        try:
            client = Client(self.address, timeout=self.cfg.compute.connect_timeout_s,
                            set_as_default=False)
        except (OSError, ValueError) as exc:  # TimeoutError is an OSError
            raise ComputeUnavailable(
                f"cannot reach the Dask scheduler at {self.address} ({exc}); check that it "
                "runs and that [compute] scheduler names it") from None
        try:
            result = loads(_Watch(client, self.address, self.cfg.compute.worker_wait_s, stop,
                                  progress).result(payload))
        finally:
            client.close()
        return with_correction(self.cfg, result, correction)


class _Watch:
    """One task on ``client``'s cluster, watched until it has a result (see
    :meth:`RemoteCalibrator.run`)."""

    def __init__(self, client: Any, address: str, worker_wait_s: float,
                 stop: threading.Event | None, progress: Callable[[str], None] | None) -> None:
        self.client, self.address, self.worker_wait_s = client, address, worker_wait_s
        self.stop, self.progress = stop, progress
        self.worker: str | None = None  # the worker seen running the task
        self.no_worker_since: float | None = None
        #: what the watch sleeps on between looks (``stop`` when given: it wakes at once)
        self._sleep = stop if stop is not None else threading.Event()

    def result(self, payload: bytes) -> bytes:
        """The task's result (pickled); see :meth:`RemoteCalibrator.run` for what it raises."""
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

    def _outcome(self, fut: Any) -> bytes:
        """The finished task's result, or its error re-raised (a worker Dask gave up on as
        :class:`ComputeUnavailable`)."""
        from distributed import KilledWorker

        try:
            return fut.result()
        except KilledWorker as exc:
            raise ComputeUnavailable(f"the Dask workers at {self.address} died running the "
                                     f"run ({exc})") from None

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
