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

Server -> simulator: ``("job", owner, job, kind, payload, word)`` with kind ``"views"`` (a
condition, the picture's colours and the condition pinned as B, or None) or
``"characteristic"`` (a condition and keyword arguments); ``("cancel", owner, word)``;
``("light", LightSource)`` (an upload already checked, given to a restarted process);
``("check", job, LightSource, shown)`` (an upload to decode and check, its errors naming the
file ``shown``; answered as a job is);
``("forget", name)`` (an upload the server dropped);
``("tick", word)`` (the word moved so that the launch in flight reaches its job's check: sent
every half slice while jobs of several owners are in flight, so a job whose turn is over gives
way, :mod:`grassd.daemon.studio.worker`); ``("stop", word)`` (every job stops, and the process
ends).
Simulator -> server: ``("ready", seconds)``, ``("msg", job, dict)``, ``("result", job,
value)``, ``("error", job, kind, message)`` with kind "input" (a StudioInputError), "superseded"
or the exception's class name.
"""

from __future__ import annotations

import asyncio
import ctypes
import itertools
import logging
import multiprocessing
import threading
from collections.abc import Callable
from dataclasses import dataclass
from multiprocessing.connection import Connection
from typing import TYPE_CHECKING, Any

import numpy as np

from grassd.daemon.studio.inputs import StudioInputError
from grassd.daemon.studio.lights import LightSource
from grassd.daemon.studio.limits import DEFAULT_LIMITS, StudioLimits
from grassd.daemon.studio.worker import Check, Superseded, Yielded
from grassd.sim.interrupt import Interrupt

if TYPE_CHECKING:
    from grassd.daemon.studio.session import Studio

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
    pixel_fields: dict[str, Any] | None = None
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


def simulator_main(conn: Connection, args: StudioArgs,
                   word: ctypes.Array[ctypes.c_int] | None = None) -> None:
    """The simulator process: build the Studio, warm it up, then run what the server sends.
    ``word``: the ``multiprocessing`` int array (``RawArray("i", 1)``) the server moves with
    every job or cancel; None: launches are not stopped in flight."""
    from grassd.daemon.core.calibration.simulation import CurveRun
    from grassd.daemon.core.runtime.freed_memory import release_freed_memory
    from grassd.daemon.studio.superseding import Superseding
    from grassd.daemon.studio.worker import Worker

    superseding = None if word is None else Superseding(np.frombuffer(word, np.int32))
    studio = args.build(None if superseding is None else superseding.interrupt)
    send_lock = threading.Lock()

    def send(item: tuple) -> None:
        with send_lock:
            conn.send(item)

    worker = Worker(slice_s=args.limits.slice_s)
    warm = worker.submit("warm-up", lambda check: studio.warm_up())

    def ready(fut) -> None:
        exc = fut.exception()
        if exc is not None:
            log.error("the studio's warm-up failed: %s: %s", type(exc).__name__, exc)
        send(("ready", 0.0 if exc else fut.result()))

    warm.add_done_callback(ready)

    def run(job: int, kind: str, payload: tuple) -> Callable:
        # a characteristic's rounds, kept when it yields to a page's job
        kept = CurveRun() if kind == "characteristic" else None

        def go(check) -> None:
            try:
                if kind == "views":
                    cond, picture, pinned = payload
                    studio.run(cond, lambda msg: send(("msg", job, msg)), check, picture,
                               pinned)
                    send(("result", job, None))
                else:
                    cond, kw = payload
                    curve = studio.characteristic(cond, check=check, resume=kept, **kw)
                    send(("result", job, curve))
            except Yielded:  # the worker queues it again, behind the page's job
                raise
            except Superseded:
                send(("error", job, "superseded", "a newer request replaced this one"))
            except StudioInputError as exc:
                send(("error", job, "input", str(exc)))
            except Exception as exc:  # a renderer or colour error: reported, the studio goes on
                log.exception("studio job failed")
                send(("error", job, type(exc).__name__, f"{type(exc).__name__}: {exc}"))
            finally:  # what the job built (a light's maps, its rounds) is resident no more
                release_freed_memory()
        return go

    def check_light(job: int, src: LightSource, shown: str) -> None:
        # decoded here once, and kept loaded for its first use; off the reader, which a
        # decode of seconds would keep from the next job or cancel
        try:
            studio.lights.add_source(src)
            studio.lights.source(src.name, shown)
            send(("result", job, None))
        except StudioInputError as exc:
            studio.lights.forget(src.name)
            send(("error", job, "input", str(exc)))
        except Exception as exc:
            studio.lights.forget(src.name)
            log.exception("checking an uploaded light failed")
            send(("error", job, type(exc).__name__, f"{type(exc).__name__}: {exc}"))
        finally:
            release_freed_memory()

    while True:
        try:
            item = conn.recv()
        except EOFError:  # the server went away
            break
        if item[0] == "job":
            _, owner, job, kind, payload, moved = item

            def skipped(fut, job=job) -> None:  # superseded while queued: go() never ran
                if not fut.cancelled() and isinstance(fut.exception(), Superseded):
                    send(("error", job, "superseded", "a newer request replaced this one"))

            worker.submit(owner, run(job, kind, payload),  # a script's gives way to a page's
                          yields=kind == "characteristic").add_done_callback(skipped)
            if superseding is not None:
                superseding.took(moved)
        elif item[0] == "cancel":
            worker.cancel(item[1])
            if superseding is not None:
                superseding.took(item[2])
        elif item[0] == "light":
            studio.lights.add_source(item[1])
        elif item[0] == "check":
            threading.Thread(target=check_light, args=item[1:], daemon=True,
                             name="grassd-studio-check").start()
        elif item[0] == "forget":
            studio.lights.forget(item[1])
        elif item[0] == "tick":
            if superseding is not None:
                superseding.took(item[1])
        elif item[0] == "stop":
            worker.cancel_all()
            if superseding is not None:
                superseding.took(item[1])
            break
    worker.stop()


class SimulatorProcess:
    """The server's handle on the simulator process: submit jobs, stream their messages,
    await their results (on the server's event loop)."""

    def __init__(self, args: StudioArgs, on_ready: Callable[[float], None]) -> None:
        from grassd.sim.errors import require_renderer

        require_renderer()  # here, in one line, rather than as a child that keeps dying
        self._args = args
        self._on_ready = on_ready
        self._jobs = itertools.count(1)
        self._pending: dict[int, tuple[asyncio.Future, Callable | None]] = {}
        self._owners: dict[int, Any] = {}  # the owner of each job in flight
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
            self._conn.send(("light", src))
        threading.Thread(target=self._read, args=(self._conn,), name="grassd-studio-reader",
                         daemon=True).start()

    def _send(self, item: tuple, supersedes: bool = False) -> None:
        """Send ``item``; one that ``supersedes`` (a job, a cancel) first moves the shared word,
        which stops the launch in flight, and carries the word's new value."""
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
                    if supersedes:
                        self._word[0] += 1
                    self._conn.send(item + (self._word[0],) if supersedes else item)
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

    def _dispatch(self, item: tuple) -> None:
        if item[0] == "ready":
            self._on_ready(item[1])
            return
        job = item[1]
        if item[0] == "msg":
            entry = self._pending.get(job)
            if entry is not None and entry[1] is not None:
                entry[1](item[2])
            return
        fut, _ = self._pending.pop(job, (None, None))
        self._owners.pop(job, None)
        if fut is None or fut.done():
            return
        if item[0] == "result":
            fut.set_result(item[2])
        elif item[2] == "superseded":
            fut.set_exception(Superseded(item[3]))
        elif item[2] == "input":
            fut.set_exception(StudioInputError(item[3]))
        else:
            fut.set_exception(RuntimeError(item[3]))

    def submit(self, owner: int, kind: str, payload: tuple,
               on_message: Callable[[dict], None] | None = None) -> asyncio.Future:
        """Run a job of ``owner`` (superseding its earlier ones); its future gets the result,
        ``on_message`` each streamed message (on the event loop)."""
        job = next(self._jobs)
        fut = self._loop.create_future()
        self._pending[job] = (fut, on_message)
        self._owners[job] = owner
        self._send(("job", owner, job, kind, payload), supersedes=True)
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
            self._send(("tick",), supersedes=True)
        except (OSError, RuntimeError):  # ending, or ended: the next job starts it again
            return
        self._schedule_tick()

    def cancel(self, owner: int) -> None:
        """Stop the owner's jobs (its page went away)."""
        self._send(("cancel", owner), supersedes=True)

    def check_light(self, source: LightSource, shown: str) -> asyncio.Future:
        """Make an uploaded light known to the simulator, which decodes and checks it (the
        server never holds its pixels) and keeps it loaded for its first use. The future gets
        None, or StudioInputError naming the file ``shown`` (the simulator has dropped it) for
        a file that is not a usable panorama; a light that passed is given again to a
        restarted process."""
        job = next(self._jobs)
        fut = self._loop.create_future()
        self._pending[job] = (fut, None)

        def passed(f: asyncio.Future) -> None:
            if not f.cancelled() and f.exception() is None:
                self._lights.append(source)

        fut.add_done_callback(passed)
        self._send(("check", job, source, shown))
        return fut

    def forget_light(self, name: str) -> None:
        """Make the simulator drop an upload (the server has dropped it and its file)."""
        self._lights = [s for s in self._lights if s.name != name]
        self._send(("forget", name))

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
                    self._conn.send(("stop", self._word[0]))
                except OSError:
                    pass
                self.alive = False
        self.proc.join(timeout=20)
        if self.proc.is_alive():
            self.proc.kill()
            self.proc.join()


