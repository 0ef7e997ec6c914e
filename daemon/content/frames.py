"""Content frames to the controllers: :class:`FrameOutput` sends the newest frame of 8-bit
levels to every controller, at most ``fps`` frames a second, on the same serial lines as the
fleet's table pushes, reconcile and the measurement's test patterns.

Interface (what the content sources code against)::

    out = FrameOutput(cfg.controllers, n_pixels, fps=30.0, fleet=fleet)
    out.offer(levels)      # uint8, shape (n_pixels,): returns at once, latest wins
    out.stats()            # FrameStats: offered, shown, dropped, fps shown, latency
    out.hold()             # a measurement takes the display: nothing sent while held
    out.release()          # ... and gives it back: the newest frame is sent again
    out.close()

``levels[i]`` is the level of display pixel ``i`` (row-major: row 0 at the top, column 0 at
the left), which each controller's ``pixels`` ranges map onto its own pixels in order. A frame
is *shown* when its SHOW was written after at least one controller acknowledged its levels;
its *latency* runs from :meth:`FrameOutput.offer` to the last controller's acknowledgement
(milliseconds).

How a frame is sent (PROTOCOL.md section 3, "The frame latch", and section 5, "Sharing a
line"): one sender thread takes the newest frame, no sooner than ``1 / fps`` after the last;
the serial lines are staged in parallel (a thread per line): holding the line's
:class:`~grassd.firmware_proto.bus_lock.BusLock`, STAGE_LEVEL to every controller on it
(SET_LEVEL to one without the latch). Once every line is staged (or ``line_wait_s`` passed),
the sender writes a broadcast SHOW on each staged line, one after another, while the line
threads still hold their lines and wait, so every controller applies the frame at once and no
request gets between a line's STAGE_LEVELs and its SHOW. A push, a status read or a test
pattern on the same line waits for at most the one frame in flight, and a frame for at most
one of their requests: while the output runs, the lines' table chunks are capped to
``push_slot_s`` of wire time (:func:`stream_chunk_bytes`). A controller that does not answer
twice in a row is left out of the next frames for a while (doubling, up to ``skip_max_s``;
a frame's levels are not retransmitted by default: the next frame replaces them), so the others
keep their rate; one that comes back (a reboot, a plug) gets the current frame with the next
one sent. Without a new frame, the newest is sent again every ``refresh_s`` (a rebooted
controller, a committed table: both show it from that SHOW on). The output attaches itself
to its ``fleet`` (:meth:`~.fleet.Fleet.attach_frames`): the fleet's pushes then stage every
controller first and commit them all while the output is held, so that no frame is shown
through the old table on some controllers and the new one on others.

The daemon closes its :class:`FrameOutput` before the :class:`~.fleet.Fleet` whose lines it
shares (a closed fleet's lines would be opened again by the next frame), and runs one output
per fleet at a time.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from collections.abc import Sequence
from concurrent.futures import Future, ThreadPoolExecutor, wait
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike

from grassd.daemon.content.status import FrameStatsJson
from grassd.daemon.core.config.settings import ControllerConfig
from grassd.daemon.core.errors import DaemonError
from grassd.daemon.core.hardware.fleet import Fleet
from grassd.firmware_proto.client import ControllerClient, ControllerUnsupported, RetryPolicy
from grassd.firmware_proto.errors import PortUnavailable, ProtocolError, TransientError
from grassd.firmware_proto.messages import MAX_CHUNK_DATA

log = logging.getLogger(__name__)

#: Frames whose latency the statistics keep (the most recent ones).
LATENCY_WINDOW = 1000
#: Seconds over which ``fps_shown`` counts shown frames.
FPS_WINDOW_S = 2.0
#: Wire bytes a TABLE_CHUNK adds to its data: header, table_id, offset, CRC, COBS, delimiter.
CHUNK_OVERHEAD_BYTES = 5 + 8 + 4 + 2 + 1


class FrameError(DaemonError):
    """A frame offered is not what the display takes (its shape or values); the message says
    which shape and values it needs."""


class FrameOutputClosed(DaemonError):
    """A frame was offered after :meth:`FrameOutput.close`; make a new output."""


@dataclass(frozen=True)
class FrameStats:
    """Counts since the output started, and recent rates.

    ``frames_offered``: frames given to :meth:`FrameOutput.offer`; ``frames_shown``: offered
    frames shown (their SHOW written after at least one controller acknowledged them);
    ``frames_dropped``: frames replaced by a newer one before they were shown (while
    waiting, or while one that reached no controller waited to be tried again); every
    offered frame ends shown or dropped, but the newest, which may still wait;
    ``frames_resent``: the newest frame sent again (after :meth:`FrameOutput.release`, or
    every ``refresh_s`` without a new one); ``fps_shown``: offered frames shown per second
    over the last :data:`FPS_WINDOW_S` seconds; ``latency_ms_median`` / ``latency_ms_p99``:
    offer to the last controller's acknowledgement over the last :data:`LATENCY_WINDOW`
    shown frames (milliseconds; None before the first); ``misses``: controllers' levels of a
    frame not delivered (no answer, a refusal, or left out while not answering); ``held``:
    a measurement holds the display now.
    """

    frames_offered: int = 0
    frames_shown: int = 0
    frames_dropped: int = 0
    frames_resent: int = 0
    fps_shown: float = 0.0
    latency_ms_median: float | None = None
    latency_ms_p99: float | None = None
    misses: int = 0
    held: bool = False

    def to_json(self) -> FrameStatsJson:
        """The figures as JSON (the fields by name, in this order)."""
        return {"frames_offered": self.frames_offered, "frames_shown": self.frames_shown,
                "frames_dropped": self.frames_dropped, "frames_resent": self.frames_resent,
                "fps_shown": self.fps_shown, "latency_ms_median": self.latency_ms_median,
                "latency_ms_p99": self.latency_ms_p99, "misses": self.misses,
                "held": self.held}


def stream_chunk_bytes(baud: int, slot_s: float) -> int:
    """The largest TABLE_CHUNK data (bytes, a power of two, 16..1016) whose request takes at
    most ``slot_s`` seconds on a line of ``baud`` bit/s (8N1: 10 bit times per byte)."""
    room = int(baud / 10 * slot_s) - CHUNK_OVERHEAD_BYTES
    size = 16
    while size * 2 <= min(room, MAX_CHUNK_DATA):
        size *= 2
    return size


@dataclass
class _Controller:
    """One controller as the sender sees it: its display pixels, whether it has the latch
    (None: not asked yet), and when it may be tried again after failing."""

    config: ControllerConfig
    pixels: np.ndarray
    latch: bool | None = None
    failures: int = 0
    skip_until: float = 0.0


@dataclass(eq=False)
class _Line:
    """One serial line: its client, its controllers, and its staging in flight (if any)."""

    client: ControllerClient
    controllers: list[_Controller] = field(default_factory=list)
    staging: Future | None = None
    turn: _Turn | None = None


@dataclass
class _Turn:
    """One line's part in one frame: ``staged`` once its STAGE_LEVELs are answered (with
    ``result``), ``shown`` once the sender wrote its SHOW (the line thread then lets go)."""

    staged: threading.Event = field(default_factory=threading.Event)
    shown: threading.Event = field(default_factory=threading.Event)
    result: _Staged | None = None


@dataclass
class _Staged:
    """What staging one line achieved for one frame: controllers reached, with or without the
    latch, controllers missed, and the monotonic time of its last acknowledgement."""

    latched: int = 0
    direct: int = 0
    missed: int = 0
    last_ack: float | None = None


def _pixel_indices(c: ControllerConfig, n_pixels: int) -> np.ndarray:
    """Display pixel indices controller ``c`` drives, in its own pixel order."""
    if not c.pixels:
        return np.zeros(0, np.int64)
    idx = np.concatenate([np.arange(a, b + 1) for a, b in c.pixels])
    if idx.min() < 0 or idx.max() >= n_pixels:
        raise FrameError(f"controller {c.name} drives pixels up to {int(idx.max())}, but the "
                         f"display has {n_pixels} (0..{n_pixels - 1}); fix its pixels ranges")
    return idx


class FrameOutput:
    """Sends the newest offered frame to every controller in ``controllers``, at most ``fps``
    frames per second (> 0), for a display of ``n_pixels`` pixels.

    ``fleet``: the :class:`~grassd.daemon.core.hardware.fleet.Fleet` whose serial lines the frames
    share (its pushes and status reads take turns with the frames, see the module docstring);
    without one the output opens the lines itself with ``policy``. ``refresh_s``: the newest
    frame is sent again after this many seconds without a new one (s, > 0).
    ``answer_timeout_s``: turn-around margin of one controller's answer to a frame's levels
    (s; the line's byte time is added), ``retries`` its retransmissions. ``skip_s`` /
    ``skip_max_s``: a controller that failed twice in a row (or whose port is gone) is left
    out of frames this long, doubling at each further failure up to ``skip_max_s`` (s).
    ``push_slot_s``: while the output runs, table chunks on its lines take at most this long
    on the wire (s). ``line_wait_s``: how long a frame waits for a line's staging (s; default
    three frame periods, at least 0.1 s): a line later than that misses the frame (the others
    show it), and every frame while it is still busy.
    """

    def __init__(self, controllers: Sequence[ControllerConfig], n_pixels: int, *,
                 fps: float = 30.0, fleet: Fleet | None = None,
                 policy: RetryPolicy | None = None, refresh_s: float = 1.0,
                 answer_timeout_s: float = 0.1, retries: int = 0, skip_s: float = 0.25,
                 skip_max_s: float = 2.0, push_slot_s: float = 0.01,
                 line_wait_s: float | None = None) -> None:
        if not fps > 0:
            raise FrameError(f"fps must be > 0 frames per second, got {fps!r}")
        if n_pixels < 1:
            raise FrameError(f"n_pixels must be >= 1, got {n_pixels!r}")
        if not refresh_s > 0:
            raise FrameError(f"refresh_s must be > 0 s, got {refresh_s!r}")
        self.n_pixels = int(n_pixels)
        self.fps = float(fps)
        self.refresh_s = float(refresh_s)
        self.answer_timeout_s = answer_timeout_s
        self.retries = retries
        self.skip_s, self.skip_max_s = skip_s, skip_max_s
        self.line_wait_s = max(3.0 / self.fps, 0.1) if line_wait_s is None else line_wait_s
        self._own_clients = fleet is None
        self._lines: dict[str, _Line] = {}
        for c in controllers:
            line = self._lines.get(c.port)
            if line is None:
                client = (fleet.client(c) if fleet is not None
                          else ControllerClient(c.port, baudrate=c.baud, policy=policy))
                client.chunk_cap = stream_chunk_bytes(c.baud, push_slot_s)
                line = self._lines[c.port] = _Line(client)
            line.controllers.append(_Controller(c, _pixel_indices(c, self.n_pixels)))
        self._cond = threading.Condition()
        self._pending: tuple[np.ndarray, float] | None = None  # (levels, offer time)
        self._newest: np.ndarray | None = None
        self._resend = False
        self._holds = 0
        self._busy = False
        self._closed = False
        self._frame_no = 0
        self._failing = False  # the last frame's send raised
        self._last_start = -np.inf
        self._last_sent = time.monotonic()
        self._offered = self._shown = self._dropped = self._resent = self._misses = 0
        self._latency: deque[float] = deque(maxlen=LATENCY_WINDOW)
        self._shown_at: deque[float] = deque()
        self._started = time.monotonic()
        lines = list(self._lines.values())
        self._pool = ThreadPoolExecutor(len(lines), thread_name_prefix="frames-line")
        self._thread = threading.Thread(target=self._run, name="frames", daemon=True)
        self._thread.start()
        self._fleet = fleet
        if fleet is not None:  # its pushes commit every controller between two frames
            fleet.attach_frames(self)

    # --- the interface -------------------------------------------------------------------
    def offer(self, levels: ArrayLike) -> None:
        """Queue ``levels`` (integers 0..255, shape (n_pixels,)) to be shown; returns at once.
        A frame offered before the previous one was sent replaces it (counted as dropped).
        Raises :class:`FrameError` for another shape or values, :class:`FrameOutputClosed`
        after :meth:`close`."""
        lv = np.asarray(levels)
        if lv.shape != (self.n_pixels,) or not np.issubdtype(lv.dtype, np.integer):
            raise FrameError(f"a frame is {self.n_pixels} integer levels (shape "
                             f"({self.n_pixels},)), got {lv.dtype} of shape {lv.shape}")
        if lv.size and (lv.min() < 0 or lv.max() > 255):
            raise FrameError(f"levels must be 0..255, got {int(lv.min())}..{int(lv.max())}")
        frame = lv.astype(np.uint8, copy=True)
        now = time.monotonic()
        with self._cond:
            if self._closed:
                raise FrameOutputClosed("this frame output is closed; make a new one")
            self._offered += 1
            if self._pending is not None:
                self._dropped += 1
            self._pending = (frame, now)
            self._newest = frame
            self._cond.notify_all()

    def stats(self) -> FrameStats:
        """The counts and recent rates (:class:`FrameStats`); safe from any thread."""
        now = time.monotonic()
        with self._cond:
            while self._shown_at and self._shown_at[0] < now - FPS_WINDOW_S:
                self._shown_at.popleft()
            span = min(FPS_WINDOW_S, now - self._started)
            fps = len(self._shown_at) / span if span > 0 else 0.0
            lat = np.asarray(self._latency)
            return FrameStats(
                self._offered, self._shown, self._dropped, self._resent, fps,
                float(np.median(lat)) * 1e3 if lat.size else None,
                float(np.percentile(lat, 99)) * 1e3 if lat.size else None,
                self._misses, self._holds > 0)

    def hold(self) -> None:
        """Stop sending frames (a measurement takes the display) until :meth:`release`;
        returns once the frame in flight, if any, is out and no line's thread uses its line
        any more (a late line's staging ended). Holds nest: each needs a release."""
        with self._cond:
            self._holds += 1
            while self._busy:
                self._cond.wait()
        busy = [ln.staging for ln in self._lines.values() if ln.staging is not None]
        wait(busy, timeout=self.line_wait_s + 1.0)

    def release(self) -> None:
        """Give the display back after :meth:`hold`: frames are sent again, starting with the
        newest one offered (at once)."""
        with self._cond:
            if self._holds == 0:
                return
            self._holds -= 1
            if self._holds == 0:
                self._resend = self._pending is None and self._newest is not None
                self._cond.notify_all()

    def close(self) -> None:
        """Stop sending and end the sender threads; the chunk cap leaves the lines. Closes
        the lines only when this output opened them (no ``fleet``)."""
        with self._cond:
            if self._closed:
                return
            self._closed = True
            self._cond.notify_all()
        if self._fleet is not None:
            self._fleet.detach_frames(self)
        self._thread.join(10)
        self._pool.shutdown(wait=True)
        for line in self._lines.values():
            line.client.chunk_cap = None
            if self._own_clients:
                line.client.close()

    def __enter__(self) -> FrameOutput:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # --- the sender ----------------------------------------------------------------------
    def _next(self) -> tuple[np.ndarray, float | None] | None:
        """Wait for the next frame to send and its slot: (levels, offer time, None for a
        resend), or None once closed. Marks the output busy."""
        with self._cond:
            while True:
                if self._closed:
                    return None
                now = time.monotonic()
                if self._holds:
                    self._cond.wait()
                    continue
                due = self._pending is not None or self._resend or (
                    self._newest is not None and now >= self._last_sent + self.refresh_s)
                slot = self._last_start + 1.0 / self.fps
                if not due:
                    wait = (self._last_sent + self.refresh_s - now
                            if self._newest is not None else None)
                    self._cond.wait(wait)
                    continue
                if now < slot:
                    self._cond.wait(slot - now)
                    continue
                if self._pending is not None:
                    levels, offered = self._pending
                    self._pending = None
                    out: tuple[np.ndarray, float | None] = (levels, offered)
                else:
                    assert self._newest is not None
                    out = (self._newest, None)
                self._resend = False
                self._busy = True
                self._last_start = now
                return out

    def _run(self) -> None:
        while (item := self._next()) is not None:
            levels, offered = item
            try:
                self._send(levels, offered)
                self._failing = False
            except Exception:  # keep sending: a dead sender would freeze the display
                if not self._failing:  # once per run of failures, not at every slot
                    log.exception("content frame %d could not be sent", self._frame_no)
                self._failing = True
                with self._cond:
                    self._not_shown(levels, offered)
            finally:
                with self._cond:
                    self._busy = False
                    self._last_sent = time.monotonic()
                    self._cond.notify_all()

    def _send(self, levels: np.ndarray, offered: float | None) -> None:
        """Stage ``levels`` on every line, then SHOW on every line at once; each line's
        thread holds its line from its first STAGE_LEVEL until its SHOW is written."""
        self._frame_no = (self._frame_no + 1) & 0xFFFF
        no = self._frame_no
        late = 0
        started: list[tuple[_Line, _Turn]] = []
        for ln in self._lines.values():
            if ln.staging is not None and not ln.staging.done():
                if not ln.turn.staged.is_set():
                    late += len(ln.controllers)  # still staging an earlier frame: misses this
                    continue
                # staged and let go, its thread just ending: wait for it, not a frame period
                wait([ln.staging], timeout=self.line_wait_s)
                if not ln.staging.done():
                    late += len(ln.controllers)
                    continue
            ln.turn = turn = _Turn()
            ln.staging = self._pool.submit(self._stage, ln, no, levels, turn)
            started.append((ln, turn))
        deadline = time.monotonic() + self.line_wait_s
        ready: list[tuple[_Line, _Staged | None]] = []
        try:
            for _, turn in started:
                turn.staged.wait(max(0.0, deadline - time.monotonic()))
            ready = [(ln, turn.result) for ln, turn in started if turn.staged.is_set()]
            late += sum(len(ln.controllers) for ln, t in started if not t.staged.is_set())
            for ln, st in ready:
                if st is not None and st.latched:
                    try:
                        ln.client.show(no, line_held=True)  # its thread waits for this
                    except PortUnavailable:
                        pass  # that line's controllers miss this frame; their next stage tells
        finally:
            for _, turn in started:
                turn.shown.set()
        staged = [st for _, st in ready if st is not None]
        reached = sum(s.latched + s.direct for s in staged)
        acks = [s.last_ack for s in staged if s.last_ack is not None]
        with self._cond:
            self._misses += late + sum(s.missed for s in staged)
            if not reached:
                self._not_shown(levels, offered)
                return
            if offered is None:
                self._resent += 1
                return
            self._shown += 1
            self._shown_at.append(time.monotonic())
            self._latency.append(max(acks) - offered)

    def _not_shown(self, levels: np.ndarray, offered: float | None) -> None:
        """A frame that reached no controller (``self._cond`` held): it is tried again at the
        next slot, unless a newer frame was offered meanwhile (then it counts as dropped); a
        resend (``offered`` None) is left to the next refresh."""
        if offered is None:
            return
        if self._pending is None:
            self._pending = (levels, offered)
        else:
            self._dropped += 1

    def _stage(self, line: _Line, no: int, levels: np.ndarray, turn: _Turn) -> None:
        """Holding the line: STAGE_LEVEL (or SET_LEVEL) to each of its controllers; then,
        still holding it, wait for the sender to write the SHOW (``turn``)."""
        with line.client.bus:
            try:
                turn.result = self._stage_controllers(line, no, levels)
            finally:
                turn.staged.set()
            turn.shown.wait(self.line_wait_s + 1.0)

    def _stage_controllers(self, line: _Line, no: int, levels: np.ndarray) -> _Staged:
        """STAGE_LEVEL (or SET_LEVEL) to each controller of ``line`` (whose lock is held)."""
        out = _Staged()
        client = line.client
        kw = {"retries": self.retries, "timeout_s": self.answer_timeout_s}
        for ctl in line.controllers:
            now = time.monotonic()
            if now < ctl.skip_until or not ctl.pixels.size:
                out.missed += bool(ctl.pixels.size)
                continue
            address = ctl.config.address
            part = levels[ctl.pixels]
            try:
                if ctl.latch is None:
                    ctl.latch = client.hello(address, **kw).supports_latch
                if ctl.latch:
                    client.stage_levels(address, no, part, **kw)
                    out.latched += 1
                else:
                    client.set_levels(address, part, **kw)
                    out.direct += 1
            except ControllerUnsupported:
                ctl.latch = False  # another board answers there now: SET_LEVEL next
                out.missed += 1
                continue
            except (TransientError, ProtocolError) as exc:
                out.missed += 1
                ctl.failures += 1
                gone = isinstance(exc, PortUnavailable)
                if gone:
                    ctl.latch = None  # what comes back on the port may be another board
                if gone or ctl.failures >= 2:  # one lost answer on a noisy line: no skip
                    k = max(ctl.failures - 2, 0)
                    delay = min(self.skip_s * 2 ** k, self.skip_max_s)
                    ctl.skip_until = time.monotonic() + delay
                continue
            ctl.failures = 0
            out.last_ack = time.monotonic()
        return out
