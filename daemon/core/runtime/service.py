"""The daemon's main loop and its wiring: setup, signals, systemd notification, reload and
the order of the work below. The parts it wires live beside it in ``grassd.daemon.core.runtime``:
``pass_errors`` (the errors a pass survives, for status), ``bundle_pipeline`` (one attempt at
a bundle, superseded light, bundles waiting in processing/), ``ambient_lux`` (manifest or lux
sensor), ``scheduled`` (the input of a run without a new bundle), ``commit`` (report, history
row, the desired tables), ``push_outcomes`` (what the history keeps of pushes), ``reconcile``
(the one code path that pushes tables), ``status``
(what status shows) and ``control_commands`` (the control socket's commands; ``control``
serves them).

One main thread does all the work (Taichi kernels run in the thread that initialised Taichi);
each *tick* (``tick_s``) it

1. applies a pending reload (SIGHUP or ``reload`` request): a new config that fails validation
   is refused and the old one kept;
2. polls the inbox and processes every complete bundle (calibrate -> commit -> push -> archive,
   or reject with the reason); a bundle whose light is older than the active table's (a late
   upload, or one held back) is archived as superseded without a run or a push; bundles
   of one pass go newest light first, so a backlog costs one calibration;
3. serves queued ``calibrate`` requests from the control socket;
4. starts a scheduled run when ``schedule.interval_s`` has passed since the last run (light of
   the last archived bundle, lux from the sensor when configured);
5. gives each feature its turn (:mod:`grassd.daemon.core.runtime.features`: a measurement when
   one is due);
6. reconciles the controllers: each one that does not report the current table gets it.

Side threads only answer the control socket (status is read from SQLite) and send the systemd
watchdog ping while the main thread shows progress (at least every ``stall_s`` seconds; a
calibration reports progress per viewpoint), so a hung main loop is restarted by systemd.

A run commits in this order: JSON report and PNG plot (atomic writes), history row ``ok``
with the table, then the push to every controller, then the bundle moves to ``archive/``. With
``[tables] granularity`` "controller"/"pixel" every controller's own table and CRC are stored
(``run_tables``) before the row turns ``ok``; push, reconcile and status then check each
controller against its own table (the run's display-wide table for one it has none for). A
crash after the commit resumes cleanly: the bundle is archived without running again and the
controllers are reconciled. SIGTERM sets a stop flag checked between viewpoints and between
controllers, so the daemon exits within one render or one table push (each push is atomic on
the controller) and an interrupted bundle is retried at the next start. The signal handlers
only write to a self-pipe; a relay thread sets the stop and reload events
(:mod:`grassd.daemon.core.runtime.signal_relay`: setting an event from a handler can deadlock on
the lock of the event the main loop waits on).
"""

from __future__ import annotations

import faulthandler
import logging
import os
import queue
import signal
import sqlite3
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import replace
from pathlib import Path

from grassd import __version__
from grassd.daemon.core.calibration.calibrate import (
    CalibrationResult,
    Calibrator,
    init_backend,
)
from grassd.daemon.core.config.settings import (
    Config,
    load_config,
    not_used_by_the_daemon,
)
from grassd.daemon.core.errors import (
    USER_ERRORS,
    ComputeUnavailable,
    ConfigError,
    DaemonError,
    RunInterrupted,
)
from grassd.daemon.core.hardware.desired_tables import DesiredTables
from grassd.daemon.core.hardware.fleet import ControllerReport, Fleet
from grassd.daemon.core.hardware.luxsensor import LuxSensor
from grassd.daemon.core.monitoring.metrics import SensorState
from grassd.daemon.core.monitoring.operator_view import OperatorSnapshot, OperatorView
from grassd.daemon.core.monitoring.status_types import DaemonState, Status, WaitingBundle
from grassd.daemon.core.runtime.ambient_lux import resolve_lux
from grassd.daemon.core.runtime.bundle_pipeline import (
    WaitingBundles,
    attempt_bundle,
    light_time,
)
from grassd.daemon.core.runtime.commit import commit_run, last_ccm
from grassd.daemon.core.runtime.compute_retry import ComputeRetry
from grassd.daemon.core.runtime.control import ControlServer
from grassd.daemon.core.runtime.control_commands import (
    Answer,
    ControlCommands,
    QueuedRequest,
    Request,
)
from grassd.daemon.core.runtime.features import Feature, Features
from grassd.daemon.core.runtime.notify import Notifier
from grassd.daemon.core.runtime.outcome import RunOutcome, RunStatus
from grassd.daemon.core.runtime.pass_errors import PassErrors, describe_error, os_action
from grassd.daemon.core.runtime.push_outcomes import PushOutcomes
from grassd.daemon.core.runtime.reconcile import (
    CurrentDesired,
    PushKind,
    reconcile_controllers,
)
from grassd.daemon.core.runtime.retention import prune, prune_measure_photos
from grassd.daemon.core.runtime.scheduled import scheduled_input
from grassd.daemon.core.runtime.signal_relay import SignalRelay
from grassd.daemon.core.runtime.statelock import StateLock
from grassd.daemon.core.runtime.status import collect_status, rss_mb, usable_run_tables
from grassd.daemon.core.store.history import History
from grassd.daemon.core.store.ingest import Bundle, Inbox
from grassd.daemon.core.store.layout import StateLayout
from grassd.daemon.core.store.manifest import CheckerPhoto
from grassd.daemon.core.store.quarantine import RetryOutcome, retry_request
from grassd.firmware_proto.client import RetryPolicy
from grassd.sim.errors import SimError
from grassd.sim.light_input import LightInput

log = logging.getLogger(__name__)

#: imported from here by the CLI, tests and benchmarks
__all__ = ["Service", "collect_status", "os_action", "rss_mb", "usable_run_tables"]


class Service:
    """The grassd daemon for ``cfg`` (``config_path`` is re-read on reload), with
    ``features`` (:mod:`grassd.daemon.core.runtime.features`; the command line gives the
    daemon's, ``grassd.daemon.cli.features``)."""

    def __init__(self, cfg: Config, *, features: Sequence[Feature] = (),
                 config_path: str | os.PathLike[str] | None = None,
                 notifier: Notifier | None = None, tick_s: float = 1.0,
                 reconcile_s: float = 2.0, stall_s: float = 300.0,
                 failure_row_s: float = 600.0, max_queued: int = 4,
                 policy: RetryPolicy | None = None, transform=None, retry_s: float = 30.0,
                 retry_max_s: float = 900.0, push_retry_s: float = 2.0,
                 push_retry_max_s: float = 300.0) -> None:
        self.cfg = cfg
        self.config_path = Path(config_path) if config_path else None
        self.notifier = notifier or Notifier()
        self.tick_s = tick_s
        self.reconcile_s = reconcile_s
        self.stall_s = stall_s
        #  reconcile backoff of a controller whose pushes fail (see
        # grassd.daemon.core.hardware.fleet):  the first retry after ``push_retry_s``, doubling up
        # to ``push_retry_max_s``
        self.push_retry_s = push_retry_s
        self.push_retry_max_s = push_retry_max_s
        self.policy = policy or RetryPolicy(timeout_s=0.25, retries=2, restarts=2,
                                            readback_retries=4)
        #: applied to every (re)loaded config, e.g. to point it at simulated hardware
        self.transform = transform or (lambda c: c)
        self.stop_event = threading.Event()
        self.reload_event = threading.Event()
        #: calibration requests from the control socket; bounded, so that clients waiting for
        #: runs cannot hold every control-socket slot (status stays answerable)
        self.requests: queue.Queue[QueuedRequest] = queue.Queue(maxsize=max_queued)
        self.features = Features(features)
        self.commands = ControlCommands(self.status, self.reload_event, self.stop_event,
                                        self.requests, self._retry_bundle,
                                        feature_for=self._feature_command)
        self.activity = "starting"
        self.started_at = time.time()
        self.last_progress = time.monotonic()
        self.last_run_at: float | None = None
        self._last_reconcile = 0.0
        self.reload_error: str | None = None
        #: the errors main-loop passes survived (OSError / SQLite), for status
        self.errors = PassErrors()
        self.runs_done = 0
        self.rss_log: list[tuple[int, float]] = []
        cfg.state_dir.mkdir(parents=True, exist_ok=True)
        #: one grassd process per state directory (daemon or one-shot), see statelock
        self.lock = StateLock(cfg.state_dir).acquire()
        try:
            self.history = History(StateLayout(cfg.state_dir).db)
            #: a controller whose pushes keep failing gets one history row per
            #: ``failure_row_s`` (its first failure, then a summary), not one per reconcile
            self.push_outcomes = PushOutcomes(self.history, failure_row_s)
            #: the tables the controllers should hold: written by the commit, read by
            #: reconcile (the one code path that pushes them) and status
            self.desired = CurrentDesired(self.history)
            #: bundles waiting for a transient failure (full disk, lux sensor down) to clear;
            #: the first retry after ``retry_s``, then doubling up to ``retry_max_s``
            self.waiting = WaitingBundles(self.history, retry_s, retry_max_s)
            self.deferred = self.waiting.bundles
            #: a scheduled or requested run the Dask cluster could not compute, retried with
            #: the same backoff
            self.compute_retry = ComputeRetry(retry_s, retry_max_s)
            #: metrics, alerts, status page, from snapshots of the status
            self.operator = OperatorView(cfg, self.history, self._operator_snapshot,
                                         self.features.page_cards(self))
            self._build(cfg)
        except BaseException:
            self.lock.release()
            raise
        self.control: ControlServer | None = None
        self._watchdog_thread: threading.Thread | None = None
        self._signals: SignalRelay | None = None

    # ------------------------------------------------------------------ setup
    def _build(self, cfg: Config) -> None:
        self.cfg = cfg
        self.inbox = Inbox(cfg.light.inbox, cfg.state_dir, self.history,
                           settle_s=cfg.light.settle_s,
                           incomplete_timeout_s=cfg.light.incomplete_timeout_s,
                           tz=cfg.site.timezone,
                           future_tolerance_s=cfg.light.future_tolerance_s,
                           site=(cfg.site.latitude, cfg.site.longitude),
                           limits=cfg.light.limits)
        self.fleet = Fleet(cfg.controllers, policy=self.policy, retry_s=self.push_retry_s,
                           retry_max_s=self.push_retry_max_s,  # a reload resets the backoff
                           on_progress=self._pushed_chunk, cancel=self.stop_event)
        # `grassd controllers` may talk on other ports while we run (see statelock)
        self.lock.note_ports(cfg.serial_ports)
        self.sensor = LuxSensor(cfg.light.modbus) if cfg.light.modbus is not None else None
        #: runs the calibrations: here (Taichi), or what a feature offers (the compute
        #: feature: the Dask cluster of [compute] scheduler)
        self.calibrator = self.features.calibrator(cfg) or Calibrator(cfg)
        self.reports_dir = StateLayout(cfg.state_dir).reports
        self.reports_dir.mkdir(parents=True, exist_ok=True)
        self.operator.configure(cfg)

    def _pushed_chunk(self) -> None:
        """A controller acknowledged a table chunk: a long push is progress too (watchdog)."""
        self.last_progress = time.monotonic()

    def _progress(self, text: str) -> None:
        self.activity = text
        self.last_progress = time.monotonic()
        self.notifier.status(text)

    def _install_signals(self) -> None:
        """SIGTERM/SIGINT stop, SIGHUP reloads, through a :class:`SignalRelay` (the handlers
        never touch an event themselves); SIGUSR1 dumps every thread's stack."""
        faulthandler.register(signal.SIGUSR1, all_threads=True)  # stack dump for debugging
        stop = (signal.SIGTERM, signal.SIGINT)
        self._signals = SignalRelay({**dict.fromkeys(stop, self.stop_event.set),
                                     signal.SIGHUP: self.reload_event.set},
                                    latched=stop).install()

    def _watchdog_loop(self) -> None:
        interval = self.notifier.watchdog_interval_s
        while not self.stop_event.wait(min(interval or 1.0, 1.0)):
            if time.monotonic() - self.last_progress <= self.stall_s:
                self.notifier.watchdog()

    # ------------------------------------------------------------------ main loop
    def run(self) -> int:
        """Run until SIGTERM/SIGINT; returns the exit status (0 = clean stop)."""
        self._install_signals()
        for note in not_used_by_the_daemon(self.cfg):
            log.warning("config: %s", note)
        self._init_renderer()
        abandoned = self.history.abandon_running("daemon stopped or crashed during the run")
        if abandoned:
            log.warning("%d run(s) left unfinished by the previous daemon marked failed",
                        abandoned)
        self.control = ControlServer(self.cfg.control_socket, self.handle_request).start()
        self._watchdog_thread = threading.Thread(target=self._watchdog_loop, name="watchdog",
                                                 daemon=True)
        self._watchdog_thread.start()
        pending = self.inbox.recover()
        self.prune()
        self.notifier.ready(f"watching {self.cfg.light.inbox}")
        self.features.restart(self, None)
        self.activity = "idle"
        log.info("grassd %s ready: inbox %s, %d controller(s), socket %s", __version__,
                 self.cfg.light.inbox, len(self.cfg.controllers), self.cfg.control_socket)
        try:
            while not self.stop_event.is_set():
                self.main_loop_pass(pending)
                pending = []
                self.stop_event.wait(self.tick_s)
        finally:
            self.shutdown()
            if self._signals is not None:  # later signals are ignored: we are done
                self._signals.close()
        return 0

    def main_loop_pass(self, pending: list[Bundle] | None = None) -> None:
        """One pass as :meth:`run` makes it: :meth:`tick`, surviving an OSError or SQLite
        error (e.g. a full or read-only disk): logged and kept as ``last_error``."""
        try:
            self.tick(pending)
        except (OSError, sqlite3.Error) as exc:  # e.g. a full or read-only disk
            self._survived(exc, "main loop", os_action(exc))
            self.errors.escaped = True

    def tick(self, pending: list[Bundle] | None = None) -> None:
        """One pass of the main loop (see module docstring). A pass that completes without
        surviving an error clears ``last_error`` (status keeps it as ``last_error_seen``),
        unless a bundle deferred by such an error still waits for its retry, or the error
        ended a pass (:meth:`main_loop_pass`) and this pass did not reconcile."""
        self.last_progress = time.monotonic()
        self.errors.in_pass = 0
        reconciled = self._last_reconcile
        self._tick(pending)
        if (self.errors.in_pass == 0 and self.errors.last is not None
                and not any(d.error for d in list(self.deferred.values()))  # a bundle
                # still waiting after its error (not retried in this pass) keeps it, and an
                # error that ended a pass (e.g. in reconcile, every reconcile_s) clears only
                # in a pass that reconciled
                and (not self.errors.escaped or self._last_reconcile != reconciled)):
            self.errors.clear()

    @property
    def last_error(self) -> str | None:
        """The error of the latest main-loop pass that survived one ("<UTC time> <line>"),
        until a later pass completes without one (see :meth:`tick`)."""
        return self.errors.last

    def _tick(self, pending: list[Bundle] | None) -> None:
        if self.reload_event.is_set():
            self.reload_event.clear()
            self.reload()
        interval = self.cfg.schedule.interval_s
        last = self.last_run_at or self.started_at
        due = interval > 0 and time.time() - last >= interval
        bundles = list(pending or [])
        now = time.monotonic()
        bundles += [d.bundle for d in list(self.deferred.values()) if d.retry_at <= now]
        try:
            if self.cfg.schedule.on_new_bundle or due:
                bundles += self.inbox.poll()
            else:  # keep watching, so that a bundle has settled when the scheduled run is due
                self.inbox.poll(claim=False)
        except (OSError, sqlite3.Error) as exc:  # e.g. the inbox's share went away: what does
            # not need it (waiting bundles, requests, scheduled runs, reconcile) goes on
            # (scanning and reading the inbox; claiming writes below processing/, rejected/)
            ib = self.inbox
            self._survived(exc, f"inbox {self.cfg.light.inbox}", os_action(
                exc, (ib.processing, ib.archive, ib.rejected), otherwise="read"))
        bundles.sort(key=light_time, reverse=True)  # newest light first (ties: in order),
        # so that a backlog costs one calibration: the older ones are then superseded
        for b in bundles:
            if self.stop_event.is_set():
                return
            self.process_bundle(b)
        while not self.stop_event.is_set():
            try:
                req = self.requests.get_nowait()
            except queue.Empty:
                break
            try:
                req.result = req.task() if req.task else self.scheduled_run("request",
                                                                            force=req.force)
            except BaseException as exc:  # the waiting client learns it now, not at its timeout
                req.result = RunOutcome(RunStatus.FAILED, error=self._describe(exc))
                raise
            finally:
                req.done.set()
        retry = self.compute_retry.due()
        if due and not bundles and not self.stop_event.is_set():
            self.scheduled_run("interval")
        elif retry and not bundles and not self.stop_event.is_set():
            self.scheduled_run(retry)
        self.features.tick(self)
        if time.monotonic() - self._last_reconcile >= self.reconcile_s:
            self.reconcile()
        if self.activity != "idle":
            self._progress("idle")

    def _describe(self, exc: BaseException, action: str = "access") -> str:
        """One line for an error a main-loop pass survives (see :func:`describe_error`)."""
        return describe_error(exc, self.cfg.state_dir, self.history.path, action)

    def _survived(self, exc: BaseException, where: str, action: str = "access") -> str:
        """Log ``exc`` (OSError / SQLite error) and keep it for status as ``last_error``."""
        return self.errors.survived(self._describe(exc, action), where)

    def shutdown(self) -> None:
        """Stop serving, close ports and the database (called once at exit)."""
        self.notifier.stopping("stopping")
        self.features.stop()
        if self.control is not None:
            self.control.stop()
        while True:  # answer anybody still waiting for a run
            try:
                req = self.requests.get_nowait()
            except queue.Empty:
                break
            req.result = RunOutcome(RunStatus.FAILED, error="daemon stopped before the run")
            req.done.set()
        self.fleet.close()
        if self.sensor is not None:
            self.sensor.close()
        self.operator.close()
        self.history.close()
        self.notifier.close()
        self.lock.release()
        log.info("grassd stopped")

    def one_shot(self, force: bool = False) -> RunOutcome:
        """`grassd calibrate --now` without a daemon: process complete bundles waiting in the
        inbox (no settle time) or, when there are none, run on the last bundle's light.

        The bundles are processed as the daemon does, newest light first; the result is that
        of the newest bundle (the one meant to make the table). A bundle whose light is older
        than the active table's is archived as superseded, not applied (the command has no
        way to name its input, so an inbox bundle is indistinguishable from a late upload,
        and "now" asks for the current light, not a return to stale light); when that is
        the newest, the result is SUPERSEDED and the CLI exits 2 with
        the reason. Without a bundle the run uses the latest applied bundle's light, which
        is never older."""
        self._init_renderer()
        self.history.abandon_running("daemon stopped or crashed during the run")
        self.inbox.settle_s = 0.0
        bundles = sorted(self.inbox.recover() + self.inbox.poll(), key=light_time,
                         reverse=True)
        results = [self.process_bundle(b) for b in bundles]
        out = results[0] if results else self.scheduled_run("request", force=force)
        self.reconcile()
        return out

    def _init_renderer(self) -> None:
        """Initialise Taichi here when the calibrations run here (not when a feature's
        calibrator sends them to a Dask cluster: this computer then needs no Taichi).
        Idempotent."""
        if isinstance(self.calibrator, Calibrator):
            from grassd.sim import backend  # RendererMissing where Taichi is not installed

            if not backend.is_initialised():
                self._progress("initialising the renderer")
            init_backend(self.cfg)

    # ------------------------------------------------------------------ reload
    def reload(self) -> bool:
        """Re-read the config file; keep the old config if the new one is invalid."""
        self.notifier.reloading()
        if self.config_path is None:
            self.notifier.ready("reload: no config file (embedded default); nothing to do")
            return False
        try:
            new = self.transform(load_config(self.config_path))
        except ConfigError as exc:
            self.reload_error = str(exc)
            log.error("reload refused, keeping the old configuration: %s", exc)
            self.notifier.ready(f"reload refused: {exc}")
            return False
        kept = []
        if new.state_dir != self.cfg.state_dir:
            # e.g. `grassd run --state-dir`: paths inside the state dir (a relative inbox,
            # cache, socket) move along with it, as they did at start
            kept.append("state_dir")
            new = new.with_state_dir(self.cfg.state_dir)
        for name in ("control_socket", "cache_dir"):
            if getattr(new, name) != getattr(self.cfg, name):
                kept.append(name)
                new = new.replace(**{name: getattr(self.cfg, name)})
        if kept:
            log.warning("reload: %s change only on restart; keeping the old value(s)",
                        ", ".join(kept))
        self.features.pause(self)  # what shares the fleet's lines lets go first
        self.fleet.close()
        if self.sensor is not None:
            self.sensor.close()
        old = self.cfg
        try:
            self._build(new)
            self._init_renderer()  # calibrating here now: Taichi here, if it can
        except (OSError, DaemonError, SimError) as exc:  # valid, but cannot be set up (e.g.
            # the inbox, or a renderer that this computer has not)
            self._build(old)
            self.features.restart(self, old)  # on the rebuilt fleet
            self.reload_error = f"{self.config_path}: {exc}"
            log.error("reload refused, keeping the old configuration: %s", exc)
            self.notifier.ready(f"reload refused: {exc}")
            return False
        self.reload_error = None
        self._last_reconcile = 0.0
        self.features.restart(self, old)
        log.info("configuration reloaded from %s", self.config_path)
        self.notifier.ready("configuration reloaded")
        return True

    # ------------------------------------------------------------------ runs
    def _resolve_lux(self, manifest_lux: float | None) -> tuple[float, str]:
        return resolve_lux(manifest_lux, self.cfg.light, self.sensor, self._progress)

    def _run_started(self, activity: str) -> None:
        self.last_run_at = time.time()
        self._progress(activity)

    def prune(self) -> None:
        """Apply ``[retention]`` (old bundles, reports, history rows) and ``[measure]
        keep_photos``; never fails a run."""
        try:
            prune(self.cfg.state_dir, self.history, self.cfg.retention,
                  reports_dir=self.reports_dir)
            if self.cfg.measure is not None:
                prune_measure_photos(StateLayout(self.cfg.state_dir).measure,
                                     self.cfg.measure.keep_photos)
        except (OSError, sqlite3.Error, DaemonError) as exc:
            log.warning("retention: pruning failed: %s", exc)

    def process_bundle(self, b: Bundle) -> RunOutcome:
        """Calibrate from bundle ``b``, commit, push, archive; or reject it with the reason.
        Then prune per ``[retention]``."""
        try:
            out = self._process_bundle(b)
        except (OSError, sqlite3.Error) as exc:  # e.g. a full disk under the database: the
            # bundle is fine; it waits in processing/ instead of being stranded there
            out = self._defer(b, self._survived(exc, f"bundle {b.name}", os_action(exc)),
                              error=True)
        self.prune()
        self.operator.after_run(out.controllers)
        return out

    def _defer(self, b: Bundle, reason: str, limit_s: float | None = None,
               error: bool = False) -> RunOutcome:
        """Leave ``b`` in processing/ and retry it with backoff (see
        :meth:`WaitingBundles.defer`)."""
        return self.waiting.defer(b, reason, limit_s=limit_s, error=error)

    def _process_bundle(self, b: Bundle) -> RunOutcome:
        out = attempt_bundle(b, history=self.history, inbox=self.inbox, light=self.cfg.light,
                             waiting=self.waiting, lux=self._resolve_lux,
                             begin=self._run_started,
                             run=lambda run_id, light, checker: self._calibrate_and_commit(
                                 run_id, light, force=False, checker=checker))
        if out.status is not RunStatus.DEFERRED:
            self.deferred.pop(b.hash, None)
        return out

    def scheduled_run(self, trigger: str, force: bool = False) -> RunOutcome:
        """A run without a new bundle: light of the last archived bundle (or the embedded
        default site), lux from the sensor when configured, else from that bundle. Then prune
        per ``[retention]``."""
        out = self._scheduled_run(trigger, force)
        if out.transient and out.compute:  # no bundle to wait: the run waits
            out = replace(out, retry_in_s=self.compute_retry.failed(trigger, out.error or ""))
        if out.status is not RunStatus.SKIPPED:
            self.prune()
            self.operator.after_run(out.controllers)
        return out

    def _scheduled_run(self, trigger: str, force: bool) -> RunOutcome:
        self._progress(f"{trigger} calibration")
        self.last_run_at = time.time()
        try:
            inp = scheduled_input(self.history, self.inbox,
                                  self.cfg.light.lux == "modbus" and self.sensor is not None,
                                  self._resolve_lux)
        except DaemonError as exc:
            log.warning("%s run skipped: %s", trigger, exc)
            return RunOutcome(RunStatus.SKIPPED, error=str(exc))
        run_id = self.history.start_run(trigger, input_hashes=inp.input_hashes, lux=inp.lux,
                                        lux_source=inp.lux_source, light_at=inp.light_at)
        return self._calibrate_and_commit(run_id, inp.light, force=force)

    def _calibrate_and_commit(self, run_id: int, light: LightInput, force: bool,
                              checker: CheckerPhoto | None = None) -> RunOutcome:
        cur = self.history.current_table()  # the active table, the run's starting point
        prev_table = None if cur is None else list(cur.lengths_um)
        desired = None if cur is None else self.desired.current(self.cfg.controllers)
        prev_own = None if cur is None else ({} if desired is None else desired.own_lengths())
        try:
            result = self.calibrator.run(light, checker=checker, previous_um=prev_table,
                                         previous_ccm=last_ccm(self.history),
                                         force=force, stop=self.stop_event,
                                         progress=self._progress, previous_tables=prev_own)
        except RunInterrupted as exc:
            self.history.finish_run(run_id, "failed", error=str(exc))
            return RunOutcome(RunStatus.INTERRUPTED, run_id, error=str(exc))
        except ComputeUnavailable as exc:  # the cluster, not the input: a bundle waits
            self.history.finish_run(run_id, "failed", error=str(exc))
            log.warning("run %d could not be computed: %s", run_id, exc)
            return RunOutcome(RunStatus.FAILED, run_id, error=str(exc), transient=True,
                              compute=True)
        except USER_ERRORS as exc:
            self.history.finish_run(run_id, "rejected", error=str(exc))
            log.warning("run %d rejected: %s", run_id, exc)
            return RunOutcome(RunStatus.REJECTED, run_id, error=str(exc))
        except Exception as exc:  # a bug must not kill the service
            log.exception("run %d failed", run_id)  # one record, its traceback below
            self.history.finish_run(run_id, "failed", error=f"internal error: {exc!r}")
            return RunOutcome(RunStatus.FAILED, run_id, error=f"internal error: {exc!r}")
        self.compute_retry.computed()
        return self._commit(run_id, result)

    def _commit(self, run_id: int, result: CalibrationResult) -> RunOutcome:
        """Commit run ``run_id`` (:func:`commit_run`), then push its tables to every
        controller right away: reconcile (the one code path that pushes) with the run's
        own push's rules (every controller tried at once, every outcome recorded)."""
        out, desired = commit_run(run_id, result, cfg=self.cfg, history=self.history,
                                  reports_dir=self.reports_dir)
        if desired is None or out.committed is None:
            return out
        self.desired.wrote(desired, self.cfg.controllers)
        self._committed(run_id)
        self._progress(f"pushing table {run_id} to {len(self.cfg.controllers)} controller(s)")
        reports = self._reconcile(PushKind.PUSH, desired)
        metrics = out.committed.metrics or {}
        log.info("run %d committed: R^2 %.5f, max deviation %.3f dE00, %d/%d controllers",
                 run_id, metrics["r2_closed_loop"] or metrics["r2_after_fit"] or 0,
                 metrics["max_dev_de00"] or 0,
                 sum(r.ok for r in reports), len(self.cfg.controllers))
        return out.with_pushes(reports)

    def _committed(self, run_id: int) -> None:
        self.runs_done += 1
        self.rss_log.append((run_id, rss_mb()))

    def reconcile(self) -> list[ControllerReport]:
        """Push the current table to every controller that does not report it (its own table
        when the run has one per controller; the run's table to any it has none for); then
        update the operator's metrics and alerts."""
        reports = self._reconcile(PushKind.RECONCILE)
        self.operator.after_reconcile(reports)
        return reports

    def _reconcile(self, kind: PushKind, desired: DesiredTables | None = None
                   ) -> list[ControllerReport]:
        """:func:`reconcile_controllers` to ``desired`` (None: the current desired tables);
        the next reconcile of the main loop is due ``reconcile_s`` after this one ended."""
        self._last_reconcile = time.monotonic()
        if desired is None:
            desired = self.desired.current(self.cfg.controllers)
        try:
            return reconcile_controllers(desired, self.fleet, self.push_outcomes,
                                         self.stop_event, kind)
        finally:
            if kind is PushKind.PUSH:  # a run's push may take long: the controllers were
                # reconciled up to its end
                self._last_reconcile = time.monotonic()

    # ------------------------------------------------------------------ control socket
    def status(self) -> Status:
        """Live status: activity, inbox counts, runs, controllers and health.

        Runs in a control-socket thread while the main thread works: it reads the main
        loop's objects once each (config and inbox are replaced on reload) and iterates only
        over snapshots of its collections (``list()`` / ``dict()`` of a dict is one C call,
        atomic under the GIL); the history database has its own lock.
        """
        cfg, inbox, seen = self.cfg, self.inbox, self.errors.seen
        features = self.features.status()
        waiting = list(self.deferred.values())
        backoff = self.fleet.backoff()
        now = time.monotonic()
        live = DaemonState(
            pid=os.getpid(), version=__version__, activity=self.activity,
            started_at=self.started_at, uptime_s=time.time() - self.started_at,
            config=cfg.source, reload_error=self.reload_error, inbox=inbox.counts(),
            rss_mb=rss_mb(), last_error=self.errors.last,
            last_error_seen=seen,
            inbox_problems=tuple(inbox.problems()),
            metrics_textfile=str(self.operator.textfile), status_page=str(self.operator.page),
            capture=features.get("capture"),
            lines=self.fleet.line_quality(),
            waiting_bundles=tuple(
                WaitingBundle(bundle=d.bundle.name, id=d.bundle.id, reason=d.reason,
                              since=d.since, retry_in_s=max(d.retry_at - now, 0.0))
                for d in waiting),
            compute_wait=self.compute_retry.snapshot(),
            content=features.get("content"))
        # its health now counts the live errors, waits and capture station too
        return collect_status(self.history, cfg, push_backoff=backoff, daemon=live,
                              desired=self.desired.current(cfg.controllers))

    def _operator_snapshot(self) -> OperatorSnapshot:
        """The status, the lux sensor's state and the capture station's last success, for
        the operator's metrics, alerts and status page."""
        sensor, capture = self.sensor, self.features.get("capture")
        return OperatorSnapshot(
            status=self.status(),
            sensor=None if sensor is None else SensorState(up=sensor.last_ok,
                                                           last_success_at=sensor.last_success_at),
            capture_at=None if capture is None else capture.last_success_at())

    def _feature_command(self, cmd: str) -> Callable[[Request], Answer] | None:
        """What answers the control-socket command ``cmd`` when a feature has it, else None."""
        feature = self.features.for_command(cmd)
        return None if feature is None else lambda req: feature.handle(self, req)

    def handle_request(self, req: Request) -> Answer:
        """Answer one control-socket request (runs in a socket thread; see
        :class:`~grassd.daemon.core.runtime.control_commands.ControlCommands`)."""
        return self.commands.handle(req)

    def _retry_bundle(self, name: str) -> RetryOutcome:
        """Put quarantined bundle ``name`` back into the inbox (in the main loop)."""
        return retry_request(self.inbox, name)
