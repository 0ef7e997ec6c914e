"""The studio's simulations run in a process of their own.

Taichi holds Python's GIL while a kernel runs (measured: a thread ticking every 5 ms saw gaps
of 113 ms during the renderer's launches), so in one process the web server could send nothing
while the renderer works: a characteristic ready after 75 ms reached the page only after the
next kernel. The server process therefore never imports Taichi; a child process (``spawn``,
as Taichi does not survive ``fork``) builds the same :class:`~grassd.daemon.studio.session.Studio`
from :class:`StudioArgs` and runs its jobs on a :class:`~grassd.daemon.studio.worker.Worker`
thread, superseding as the server says. Messages are pickled over one pipe each way.

The GIL also keeps the simulator's own threads from reading a message while a launch runs, so
the two processes share one more word (:mod:`grassd.sim.interrupt`): the server adds one to it
with every job or cancel it sends, and sends the new value along; a launch in flight stops
within its current camera path once the word moves, and the simulator takes the message in
(:mod:`grassd.daemon.studio.superseding`) before it decides whether to finish the launch (its
skipped paths) or stop the job; on the CPU only (``Renderer.interruptible``). So a newer
input does not wait for the launch in flight, and the studio's launches can each take a whole
round (:func:`~grassd.daemon.studio.session.Studio.characteristic`).

Server -> simulator (:data:`ToSimulator`): :class:`RunJob` (a :class:`ViewsJob`, a page's
input, or a :class:`CurveJob`, a characteristic), :class:`Cancel`, :class:`AddLight` (an upload
already checked, given to a restarted process), :class:`CheckLight` (an upload to decode and
check, answered as a job is), :class:`ForgetLight` (an upload the server dropped),
:class:`Tick` (the word moved so that the launch in flight reaches its job's check: sent every
half slice while jobs of several owners are in flight, so a job whose turn is over gives way,
:mod:`grassd.daemon.studio.worker`) and :class:`Stop` (every job stops, and the process ends);
those that supersede carry the word's new value.
Simulator -> server (:data:`FromSimulator`): :class:`Ready`, :class:`JobMessage` (a view
streamed), :class:`JobResult`, :class:`JobError`.
"""

from __future__ import annotations

import asyncio
import ctypes
import itertools
import logging
import multiprocessing
import threading
from collections.abc import Callable
from concurrent.futures import Future
from dataclasses import dataclass
from multiprocessing.connection import Connection
from typing import TYPE_CHECKING

import numpy as np

from grassd.daemon.studio.inputs import StudioInputError
from grassd.daemon.studio.lights import LightSource
from grassd.daemon.studio.limits import DEFAULT_LIMITS, StudioLimits
from grassd.daemon.studio.messages import PageMessage
from grassd.daemon.studio.worker import Check, Superseded, Worker, Yielded
from grassd.sim.interrupt import Interrupt

if TYPE_CHECKING:
    from grassd.daemon.core.calibration.simulation import SimulatedCurve
    from grassd.daemon.core.config.settings import PixelValue
    from grassd.daemon.studio.inputs import Condition
    from grassd.daemon.studio.session import CharacteristicArgs, Studio
    from grassd.daemon.studio.superseding import Superseding

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class StudioArgs:
    """What builds a :class:`~grassd.daemon.studio.session.Studio` in either process: the
    config (``config_path``/``state_dir`` as ``grassd studio`` was given them), the light
    sources, the fitted pixel's fields and where they came from, the daemon's active table
    (256 um values), the Taichi arch and the studio's caps."""

    config_path: str | None
    state_dir: str | None
    sources: tuple[LightSource, ...]
    pixel_fields: dict[str, PixelValue] | None = None
    pixel_source: str = "config"
    active_um: tuple[int, ...] | None = None
    arch: str = "cpu"
    limits: StudioLimits = DEFAULT_LIMITS

    def build(self, interrupts: Callable[[Check], Interrupt] | None = None) -> Studio:
        """The Studio these arguments describe (``interrupts``: see
        :class:`~grassd.daemon.studio.session.Studio`)."""
        from grassd.daemon.core.config.settings import resolve_config
        from grassd.daemon.studio.lights import Lights
        from grassd.daemon.studio.session import Studio

        cfg = resolve_config(self.config_path, self.state_dir)
        return Studio(cfg, Lights(list(self.sources), limits=self.limits),
                      pixel_fields=self.pixel_fields,
                      pixel_source=self.pixel_source,
                      active_um=None if self.active_um is None else np.array(self.active_um),
                      arch=self.arch, interrupts=interrupts)


@dataclass(frozen=True)
class ViewsJob:
    """A page's input: every view of ``cond``, the display showing ``picture`` (its colours,
    rows x cols x 3 sRGB; None: no picture), with the condition ``pinned`` beside it as B."""

    cond: Condition
    picture: np.ndarray | None = None
    pinned: Condition | None = None


@dataclass(frozen=True)
class CurveJob:
    """A characteristic of ``cond`` run with ``args`` (an API request's, a script's: it gives
    way to a page's job)."""

    cond: Condition
    args: CharacteristicArgs


@dataclass(frozen=True)
class RunJob:
    """Run ``work`` as job ``job`` of ``owner``, superseding the owner's earlier ones."""

    owner: int
    job: int
    work: ViewsJob | CurveJob
    word: int


@dataclass(frozen=True)
class Cancel:
    """Stop the owner's jobs (its page went away)."""

    owner: int
    word: int


@dataclass(frozen=True)
class AddLight:
    """An upload the server checked before (given to a restarted process)."""

    source: LightSource


@dataclass(frozen=True)
class CheckLight:
    """An upload to decode and check, its errors naming the file ``shown``; answered as job
    ``job`` is."""

    job: int
    source: LightSource
    shown: str


@dataclass(frozen=True)
class ForgetLight:
    """An upload the server dropped."""

    name: str


@dataclass(frozen=True)
class Tick:
    """The word moved, so that the launch in flight reaches its job's check."""

    word: int


@dataclass(frozen=True)
class Stop:
    """Every job stops, and the process ends."""

    word: int


#: What the server sends the simulator.
ToSimulator = RunJob | Cancel | AddLight | CheckLight | ForgetLight | Tick | Stop


@dataclass(frozen=True)
class Ready:
    """The studio is warm, after ``seconds`` (0: its warm-up failed)."""

    seconds: float


@dataclass(frozen=True)
class JobMessage:
    """A view of job ``job``, streamed to its page."""

    job: int
    msg: PageMessage


@dataclass(frozen=True)
class JobResult:
    """Job ``job`` ended: its characteristic (None for the views, which were streamed, and a
    light checked)."""

    job: int
    value: SimulatedCurve | None


@dataclass(frozen=True)
class JobError:
    """Job ``job`` failed: ``kind`` "input" (a StudioInputError), "superseded" or the
    exception's class name, and its ``message``."""

    job: int
    kind: str
    message: str


#: What the simulator sends the server.
FromSimulator = Ready | JobMessage | JobResult | JobError


class _Simulator:
    """The simulator process's side: the Studio, the worker its jobs run on, and the pipe back
    to the server."""

    def __init__(self, conn: Connection, args: StudioArgs, superseding: Superseding | None
                 ) -> None:
        self.conn = conn
        self.superseding = superseding
        self.studio = args.build(None if superseding is None else superseding.interrupt)
        self.worker = Worker(slice_s=args.limits.slice_s)
        self._send_lock = threading.Lock()

    def send(self, item: FromSimulator) -> None:
        """Send ``item`` to the server (from any of the process's threads)."""
        with self._send_lock:
            self.conn.send(item)

    def warm_up(self) -> None:
        """Warm the studio up on the worker, then say :class:`Ready`."""
        def ready(fut: Future[float]) -> None:
            exc = fut.exception()
            if exc is not None:
                log.error("the studio's warm-up failed: %s: %s", type(exc).__name__, exc)
            self.send(Ready(0.0 if exc else fut.result()))

        self.worker.submit("warm-up", lambda check: self.studio.warm_up()).add_done_callback(
            ready)

    def _failed(self, job: int, exc: Exception, what: str) -> None:
        """Say how job ``job`` failed: a StudioInputError as the input's fault, another
        exception (a renderer or colour error, logged as ``what`` failing) by its class."""
        if isinstance(exc, StudioInputError):
            self.send(JobError(job, "input", str(exc)))
        else:
            log.exception("%s failed", what)
            self.send(JobError(job, type(exc).__name__, f"{type(exc).__name__}: {exc}"))

    def job(self, item: RunJob) -> Callable[[Check], None]:
        """What the worker runs for ``item``: its views streamed, or its characteristic
        answered; each error said as :class:`JobError`, the studio going on."""
        from grassd.daemon.core.calibration.simulation import CurveRun
        from grassd.daemon.core.runtime.freed_memory import release_freed_memory

        work, job = item.work, item.job
        # a characteristic's rounds, kept when it yields to a page's job
        kept = CurveRun() if isinstance(work, CurveJob) else None

        def go(check: Check) -> None:
            try:
                if isinstance(work, ViewsJob):
                    self.studio.run(work.cond, lambda msg: self.send(JobMessage(job, msg)),
                                    check, work.picture, work.pinned)
                    self.send(JobResult(job, None))
                else:
                    curve = self.studio.characteristic(work.cond, check=check, resume=kept,
                                                       **work.args)
                    self.send(JobResult(job, curve))
            except Yielded:  # the worker queues it again, behind the page's job
                raise
            except Superseded:
                self.send(JobError(job, "superseded", "a newer request replaced this one"))
            except Exception as exc:  # said; the studio goes on
                self._failed(job, exc, "studio job")
            finally:  # what the job built (a light's maps, its rounds) is resident no more
                release_freed_memory()
        return go

    def check_light(self, item: CheckLight) -> None:
        """Decode and check an upload, kept loaded for its first use (on a thread of its own,
        off the reader, which a decode of seconds would keep from the next job or cancel)."""
        from grassd.daemon.core.runtime.freed_memory import release_freed_memory

        lights = self.studio.lights
        try:
            lights.add_source(item.source)
            lights.source(item.source.name, item.shown)
            self.send(JobResult(item.job, None))
        except Exception as exc:
            lights.forget(item.source.name)
            self._failed(item.job, exc, "checking an uploaded light")
        finally:
            release_freed_memory()

    def took(self, word: int) -> None:
        """The message that moved the word to ``word`` is taken in."""
        if self.superseding is not None:
            self.superseding.took(word)

    def take(self, item: ToSimulator) -> bool:
        """Act on one message of the server; False once it says :class:`Stop`."""
        if isinstance(item, RunJob):
            def skipped(fut: Future[None], job: int = item.job) -> None:
                # superseded while queued: go() never ran
                if not fut.cancelled() and isinstance(fut.exception(), Superseded):
                    self.send(JobError(job, "superseded", "a newer request replaced this one"))

            self.worker.submit(item.owner, self.job(item),  # a script's gives way to a page's
                               yields=isinstance(item.work, CurveJob)).add_done_callback(skipped)
            self.took(item.word)
        elif isinstance(item, Cancel):
            self.worker.cancel(item.owner)
            self.took(item.word)
        elif isinstance(item, AddLight):
            self.studio.lights.add_source(item.source)
        elif isinstance(item, CheckLight):
            threading.Thread(target=self.check_light, args=(item,), daemon=True,
                             name="grassd-studio-check").start()
        elif isinstance(item, ForgetLight):
            self.studio.lights.forget(item.name)
        elif isinstance(item, Tick):
            self.took(item.word)
        elif isinstance(item, Stop):
            self.worker.cancel_all()
            self.took(item.word)
            return False
        return True


def simulator_main(conn: Connection, args: StudioArgs,
                   word: ctypes.Array[ctypes.c_int] | None = None) -> None:
    """The simulator process: build the Studio, warm it up, then run what the server sends.
    ``word``: the ``multiprocessing`` int array (``RawArray("i", 1)``) the server moves with
    every job or cancel; None: launches are not stopped in flight."""
    from grassd.daemon.studio.superseding import Superseding

    sim = _Simulator(conn, args,
                     None if word is None else Superseding(np.frombuffer(word, np.int32)))
    sim.warm_up()
    while True:
        try:
            item = conn.recv()
        except EOFError:  # the server went away
            break
        if not sim.take(item):
            break
    sim.worker.stop()


class SimulatorProcess:
    """The server's handle on the simulator process: submit jobs, stream their messages,
    await their results (on the server's event loop)."""

    def __init__(self, args: StudioArgs, on_ready: Callable[[float], None]) -> None:
        from grassd.sim.errors import require_renderer

        require_renderer()  # here, in one line, rather than as a child that keeps dying
        self._args = args
        self._on_ready = on_ready
        self._jobs = itertools.count(1)
        self._pending: dict[int, tuple[asyncio.Future[SimulatedCurve | None],
                                       Callable[[PageMessage], None] | None]] = {}
        self._owners: dict[int, int] = {}  # the owner of each job in flight
        self._tick: asyncio.TimerHandle | None = None
        self._lock = threading.Lock()
        self._loop = asyncio.get_running_loop()
        self._lights: list[LightSource] = []  # uploads, given again to a restarted process
        self.restarts = 0
        self._stopped = False
        self._start()

    def _start(self) -> None:
        ctx = multiprocessing.get_context("spawn")
        self._conn, child = ctx.Pipe()
        self._word = ctx.RawArray("i", 1)  # moved with every job and cancel (Superseding)
        self.proc = ctx.Process(target=simulator_main, args=(child, self._args, self._word),
                                name="grassd-studio-simulator", daemon=True)
        self.proc.start()
        child.close()
        self.alive = True
        for src in self._lights:
            self._conn.send(AddLight(src))
        threading.Thread(target=self._read, args=(self._conn,), name="grassd-studio-reader",
                         daemon=True).start()

    def _send(self, item: ToSimulator | Callable[[int], RunJob | Cancel | Tick]) -> None:
        """Send ``item``; one that supersedes (a job, a cancel, a tick) is built from the
        shared word, which it first moves (that stops the launch in flight), and carries the
        word's new value."""
        with self._lock:
            if self._stopped:
                raise RuntimeError("the studio is stopping: its simulator process has ended")
            for attempt in (1, 2):
                if not self.alive:  # it died (a crash in the renderer): a fresh one takes over
                    self.restarts += 1
                    log.warning("the studio's simulator process ended (exit code %s); "
                                "starting it again", self.proc.exitcode)
                    self._start()
                try:
                    if callable(item):
                        self._word[0] += 1
                        self._conn.send(item(self._word[0]))
                    else:
                        self._conn.send(item)
                    return
                except OSError:  # died before the reader saw it
                    self.alive = False
                    if attempt == 2:
                        raise

    def _read(self, conn: Connection) -> None:
        while True:
            try:
                item = conn.recv()
            except (EOFError, OSError):
                self._loop.call_soon_threadsafe(self._gone, conn)
                return
            self._loop.call_soon_threadsafe(self._dispatch, item)

    def _gone(self, conn: Connection) -> None:
        if conn is not self._conn:
            return
        self.alive = False
        self.proc.join(timeout=0.2)
        for fut, _ in self._pending.values():
            if not fut.done():
                fut.set_exception(RuntimeError(
                    f"the studio's simulator process ended (exit code {self.proc.exitcode}) "
                    f"during this request; it starts again with the next one"))
        self._pending.clear()
        self._owners.clear()

    def _dispatch(self, item: FromSimulator) -> None:
        if isinstance(item, Ready):
            self._on_ready(item.seconds)
            return
        if isinstance(item, JobMessage):
            entry = self._pending.get(item.job)
            if entry is not None and entry[1] is not None:
                entry[1](item.msg)
            return
        fut, _ = self._pending.pop(item.job, (None, None))
        self._owners.pop(item.job, None)
        if fut is None or fut.done():
            return
        if isinstance(item, JobResult):
            fut.set_result(item.value)
        elif item.kind == "superseded":
            fut.set_exception(Superseded(item.message))
        elif item.kind == "input":
            fut.set_exception(StudioInputError(item.message))
        else:
            fut.set_exception(RuntimeError(item.message))

    def submit(self, owner: int, work: ViewsJob | CurveJob,
               on_message: Callable[[PageMessage], None] | None = None
               ) -> asyncio.Future[SimulatedCurve | None]:
        """Run ``work`` as a job of ``owner`` (superseding its earlier ones); its future gets
        the result (a :class:`CurveJob`'s characteristic; None for a :class:`ViewsJob`, whose
        views are streamed), ``on_message`` each streamed message (on the event loop)."""
        job = next(self._jobs)
        fut: asyncio.Future[SimulatedCurve | None] = self._loop.create_future()
        self._pending[job] = (fut, on_message)
        self._owners[job] = owner
        self._send(lambda word: RunJob(owner, job, work, word))
        self._schedule_tick()
        return fut

    def _schedule_tick(self) -> None:
        """Tick every half slice while jobs of two owners or more are in flight."""
        if self._tick is None and len(set(self._owners.values())) >= 2:
            self._tick = self._loop.call_later(self._args.limits.slice_s / 2, self._ticked)

    def _ticked(self) -> None:
        self._tick = None
        if self._stopped or len(set(self._owners.values())) < 2:
            return
        try:
            self._send(Tick)
        except (OSError, RuntimeError):  # ending, or ended: the next job starts it again
            return
        self._schedule_tick()

    def cancel(self, owner: int) -> None:
        """Stop the owner's jobs (its page went away)."""
        self._send(lambda word: Cancel(owner, word))

    def check_light(self, source: LightSource, shown: str
                    ) -> asyncio.Future[SimulatedCurve | None]:
        """Make an uploaded light known to the simulator, which decodes and checks it (the
        server never holds its pixels) and keeps it loaded for its first use. The future gets
        None, or StudioInputError naming the file ``shown`` (the simulator has dropped it) for
        a file that is not a usable panorama; a light that passed is given again to a
        restarted process."""
        job = next(self._jobs)
        fut: asyncio.Future[SimulatedCurve | None] = self._loop.create_future()
        self._pending[job] = (fut, None)

        def passed(f: asyncio.Future[SimulatedCurve | None]) -> None:
            if not f.cancelled() and f.exception() is None:
                self._lights.append(source)

        fut.add_done_callback(passed)
        self._send(CheckLight(job, source, shown))
        return fut

    def forget_light(self, name: str) -> None:
        """Make the simulator drop an upload (the server has dropped it and its file)."""
        self._lights = [s for s in self._lights if s.name != name]
        self._send(ForgetLight(name))

    def stop(self) -> None:
        """End the simulator process (nothing is sent after): its jobs stop, the launch in
        flight too through the word, so on the CPU it ends within a camera path rather than
        after its launch; on a GPU, or during its warm-up (which no job's check stops), after
        the launch or the warm-up, killed if that takes more than 20 s."""
        with self._lock:
            self._stopped = True
            if self.alive:
                try:
                    self._word[0] += 1
                    self._conn.send(Stop(self._word[0]))
                except OSError:
                    pass
                self.alive = False
        self.proc.join(timeout=20)
        if self.proc.is_alive():
            self.proc.kill()
            self.proc.join()


