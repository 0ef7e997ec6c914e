"""The player: which source the display shows, and its frames to the controllers at
``[content] fps``.

Sources, highest priority first: a live sender (sACN, Art-Net), a script's frame or a
picture asked for (control socket, ``grassd show``), the playlist, the idle picture. A live
source shows while its packets come; gone silent, its last frame is held ``hold_s`` and
then the next source takes over (a stream-terminated sACN source at once). A script's frame
or a picture stays for the time its request gives. The playlist plays the entries allowed at
the local hour in order, each for its duration, looping. With nothing to show, no frame is
sent (the display keeps its last one).

While a source shows, a frame goes to the sink every ``1 / fps`` s; a live packet arriving
when the last frame went out at least that long ago goes out at once (so the latency is not
the tick's). Every frame is the display's levels (n_pixels,) uint8, row-major from the top
left. RGB pictures become levels through
:func:`~grassd.daemon.content.colour_map.levels_for_picture` with the colours of the
current calibration (re-mapped when they change).
"""

from __future__ import annotations

import collections
import logging
import threading
import time
import weakref
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from grassd.daemon.content.colour_map import DisplayColours
from grassd.daemon.content.config import ContentConfig, PlaylistEntry
from grassd.daemon.content.library import PictureLibrary
from grassd.daemon.content.mapping import MappedAnimation
from grassd.daemon.content.merge import LiveMerger
from grassd.daemon.content.pictures import Animation
from grassd.daemon.content.pixel_order import stream_to_display
from grassd.daemon.content.receiver import LiveReceiver, Protocol
from grassd.daemon.content.sink import FrameSink
from grassd.daemon.content.status import ContentSource, ContentStatus

log = logging.getLogger(__name__)

def sacn_group(universe: int) -> str:
    """The E1.31 multicast address of ``universe``: 239.255.(hi byte).(lo byte)."""
    return f"239.255.{universe >> 8}.{universe & 255}"


#: seconds the frames-per-second figures look back
RATE_WINDOW_S = 2.0
#: live latencies kept for the median and p99
LATENCY_SAMPLES = 1024
#: the longest a script's frame or an asked-for picture may stay [s] (a day)
MAX_REQUEST_S = 86400.0


@dataclass
class _Playing:
    """An animation being shown: since ``start`` (monotonic s) until ``until``."""

    anim: Animation
    start: float
    until: float
    #: its levels, mapped off the player's thread; None: levels as given (``fixed``)
    mapped: MappedAnimation | None = None
    fixed: NDArray[np.uint8] | None = None  # (1, n_pixels) a script's frame, never mapped


class ContentPlayer:
    """Plays ``cfg`` on a ``rows`` x ``cols`` display into ``sink``.

    ``colours()`` gives the current calibration's predicted colours (None before one);
    ``hour()`` the local hour (0..23) for the playlist; ``clock`` the monotonic clock [s].
    ``live`` False starts no receiver (``grassd show`` without a daemon).
    """

    def __init__(self, cfg: ContentConfig, rows: int, cols: int, sink: FrameSink, *,
                 colours: Callable[[], DisplayColours | None] = lambda: None,
                 hour: Callable[[], int] = lambda: time.localtime().tm_hour,
                 clock: Callable[[], float] = time.monotonic, live: bool = True) -> None:
        self.cfg = cfg
        self.rows, self.cols = rows, cols
        self.n_pixels = rows * cols
        self.sink = sink
        self.colours = colours
        self.hour = hour
        self.clock = clock
        self.period_s = 1.0 / cfg.fps
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self._thread: threading.Thread | None = None
        self.receivers: dict[ContentSource, LiveReceiver] = {}
        self.mergers: dict[ContentSource, LiveMerger] = {}
        if live:
            self._start_receivers()
        order = stream_to_display(rows, cols, cfg.order, cfg.serpentine, cfg.first)
        self._order = order
        self._request: _Playing | None = None
        self._request_name = ""
        self._playlist: list[PlaylistEntry] = list(cfg.playlist)
        self._pl_index = -1
        self._pl_playing: _Playing | None = None
        self._idle: _Playing | None = None
        #: the playlist's and the idle picture's files, read off this thread
        self.library = PictureLibrary([e.file for e in self._playlist]
                                      + ([cfg.idle] if cfg.idle is not None else []),
                                      rows, cols, cfg.max_picture_mib << 20)
        #: the mappings of the animations shown (dropped with them)
        self._maps: weakref.WeakKeyDictionary[Animation, MappedAnimation] = \
            weakref.WeakKeyDictionary()
        self._last_out = float("-inf")
        self._seen_in: dict[ContentSource, int] = {}
        self.source = ContentSource.NONE
        self.detail = ""
        self.frames_out = 0
        self.dropped = 0
        self._latency: collections.deque[float] = collections.deque(maxlen=LATENCY_SAMPLES)
        #: (time, frames out, frames in) at every tick, for the rates over RATE_WINDOW_S
        self._rate: collections.deque[tuple[float, int, int]] = collections.deque(
            maxlen=int(RATE_WINDOW_S * cfg.fps) + 2)

    def _start_receivers(self) -> None:
        specs = [(ContentSource.SACN, Protocol.SACN, self.cfg.sacn,
                  self.cfg.sacn.universe, self.cfg.sacn.multicast),
                 (ContentSource.ARTNET, Protocol.ARTNET, self.cfg.artnet,
                  self.cfg.artnet.port_address, False)]
        try:
            for source, proto, rc, first, multicast in specs:
                if not rc.enabled:
                    continue
                merger = LiveMerger(self.n_pixels, first, rc.start_channel,
                                    rc.source_timeout_s, rc.max_sources)
                groups = tuple(sacn_group(u) for u in merger.universes) if multicast else ()
                self.receivers[source] = LiveReceiver(proto, rc.bind, rc.port, merger,
                                                      self._wake.set, groups)
                self.mergers[source] = merger
        except BaseException:
            for r in self.receivers.values():
                r.stop()
            raise

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> ContentPlayer:
        """Start the receivers, reading the pictures and the player's thread."""
        self.library.start()
        for r in self.receivers.values():
            r.start()
        self._thread = threading.Thread(target=self._run, name="content-player", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        """Stop the thread and the receivers."""
        self._stop.set()
        self._wake.set()
        if self._thread is not None:
            self._thread.join(2)
        for r in self.receivers.values():
            r.stop()
        self.library.stop()

    def _run(self) -> None:
        next_at = self.clock()
        while not self._stop.is_set():
            wait = next_at - self.clock()
            if wait > 0:
                self._wake.wait(wait)
            self._wake.clear()
            now = self.clock()
            early = self._last_out + self.period_s - now
            if early > 0 and now < next_at:  # a packet too soon after the last frame: it
                self._stop.wait(min(early, next_at - now))  # goes once the period is up
                now = self.clock()
            if self._stop.is_set():
                return
            try:
                self.tick(now)
            except Exception:  # a bug must not stop the display's content
                log.exception("content player: unexpected error (still playing)")
            next_at = next_at + self.period_s if now >= next_at else now + self.period_s
            if next_at < now:  # fell behind: no burst to catch up
                next_at = now + self.period_s

    # ------------------------------------------------------------------ requests
    def set_frame(self, levels: NDArray[np.uint8], hold_s: float | None = None) -> None:
        """Show the display levels ``levels`` (n_pixels,) uint8 (row-major from the top
        left) for ``hold_s`` seconds (default ``[content] hold_s``), above the playlist."""
        arr = np.asarray(levels, np.uint8).reshape(self.n_pixels)
        hold = self.cfg.hold_s if hold_s is None else hold_s
        anim = Animation(arr.reshape(1, self.rows, self.cols, 1).repeat(3, -1),
                         np.array([hold or self.period_s]), "script frame")
        now = self.clock()
        with self._lock:
            self._request = _Playing(anim, now, now + hold, fixed=arr.reshape(1, -1).copy())
            self._request_name = "script frame"
        self._wake.set()

    def show(self, anim: Animation, duration_s: float) -> None:
        """Play ``anim`` (looping) for ``duration_s`` seconds, above the playlist."""
        now = self.clock()
        with self._lock:
            self._request = _Playing(anim, now, now + duration_s)
            self._request_name = anim.name
        self._wake.set()

    def stop_request(self) -> None:
        """End a script's frame or an asked-for picture now."""
        with self._lock:
            self._request = None
        self._wake.set()

    # ------------------------------------------------------------------ choosing
    def tick(self, now: float) -> NDArray[np.uint8] | None:
        """Choose the source at monotonic ``now``, offer its frame to the sink and return it
        (None: nothing to show, nothing offered)."""
        frame, source, detail = self._choose(now)
        self.source, self.detail = source, detail
        if frame is not None:
            self.sink.offer(frame)
            self.frames_out += 1
            self._last_out = now
        self._sample_rate(now)
        return frame

    def _choose(self, now: float) -> tuple[NDArray[np.uint8] | None, ContentSource, str]:
        live = self._live(now)
        if live is not None:
            return live
        with self._lock:
            req = self._request
            if req is not None and now >= req.until:
                self._request = req = None
        if req is not None:
            return self._frame_of(req, now), ContentSource.SCRIPT, self._request_name
        pl = self._playlist_frame(now)
        if pl is not None:
            return pl
        idle = self._idle_picture(now)
        if idle is not None:
            return self._frame_of(idle, now), ContentSource.IDLE, idle.anim.name
        return None, ContentSource.NONE, ""

    def _live(self, now: float) -> tuple[NDArray[np.uint8], ContentSource, str] | None:
        """The freshest live frame still within ``hold_s`` (and the frame period: with
        ``hold_s = 0`` a packet shows until the next tick) of its newest packet."""
        best = None
        for source, merger in self.mergers.items():
            f = merger.frame(now)
            if f is not None and now - f.at <= self.cfg.hold_s + self.period_s and (
                    best is None or f.at > best[1].at):
                best = (source, f)
        if best is None:
            return None
        source, f = best
        merger = self.mergers[source]
        new_in = merger.frames_in - self._seen_in.get(source, 0)
        if new_in > 0:
            self._latency.append(now - f.at)
            self.dropped += new_in - 1
            self._seen_in[source] = merger.frames_in
        levels = np.empty(self.n_pixels, np.uint8)
        levels[self._order] = f.levels
        return levels, source, f"{f.senders} sender(s)"

    def _frame_of(self, p: _Playing, now: float) -> NDArray[np.uint8]:
        """The levels of the animation ``p`` at ``now``, mapped with the current colours."""
        if p.fixed is not None:
            return p.fixed[0]
        if p.mapped is None:  # one mapping per animation, whichever entry plays it again
            p.mapped = self._maps.get(p.anim)
            if p.mapped is None:
                p.mapped = self._maps[p.anim] = MappedAnimation(p.anim, self.cfg.map,
                                                                self.cfg.normalise)
        return p.mapped.levels(self._current_colours())[p.anim.index_at(now - p.start)]

    def _current_colours(self) -> DisplayColours | None:
        if self.cfg.map != "nearest_de00":
            return None
        try:
            return self.colours()
        except Exception:  # the calibration's colours unreadable: luminance meanwhile
            log.exception("content: the calibration's colours cannot be read")
            return None

    def _playlist_frame(self, now: float
                        ) -> tuple[NDArray[np.uint8], ContentSource, str] | None:
        """The playlist's frame: the entry playing, or the next one allowed at this hour
        whose file has been read (one not read yet, or unreadable, is passed over)."""
        if not self._playlist:
            return None
        p = self._pl_playing
        hour = self.hour()
        if p is not None and (now >= p.until or
                              not self._playlist[self._pl_index].plays_at(hour)):
            p = self._pl_playing = None
        if p is None:
            for step in range(1, len(self._playlist) + 1):
                i = (self._pl_index + step) % len(self._playlist)
                entry = self._playlist[i]
                anim = self.library.get(entry.file) if entry.plays_at(hour) else None
                if anim is not None:
                    self._pl_index = i
                    p = self._pl_playing = _Playing(anim, now, now + entry.duration_s)
                    break
        if p is None:
            return None
        return self._frame_of(p, now), ContentSource.PLAYLIST, p.anim.name

    def _idle_picture(self, now: float) -> _Playing | None:
        if self._idle is None and self.cfg.idle is not None:
            anim = self.library.get(self.cfg.idle)
            if anim is not None:
                self._idle = _Playing(anim, now, float("inf"))
        return self._idle

    # ------------------------------------------------------------------ status
    def _sample_rate(self, now: float) -> None:
        self._rate.append((now, self.frames_out, self.frames_in))

    @property
    def frames_in(self) -> int:
        """Live frames received since start (all receivers)."""
        return sum(m.frames_in for m in self.mergers.values())

    def status(self) -> ContentStatus:
        """A snapshot for status and metrics (see :class:`ContentStatus`)."""
        now = self.clock()
        samples = [x for x in list(self._rate) if x[0] >= now - RATE_WINDOW_S]
        out_rate = in_rate = 0.0
        if len(samples) >= 2 and samples[-1][0] > samples[0][0]:
            (t0, o0, i0), (t1, o1, i1) = samples[0], samples[-1]
            out_rate, in_rate = (o1 - o0) / (t1 - t0), (i1 - i0) / (t1 - t0)
        lat = np.asarray(list(self._latency)) * 1000.0
        colours = self._current_colours()
        mapping = self.cfg.map if self.cfg.map != "nearest_de00" or colours is not None \
            else "luminance (no calibration's colours yet)"
        return ContentStatus(
            source=self.source, detail=self.detail, frames_out_per_s=out_rate,
            frames_in_per_s=in_rate, frames_out=self.frames_out, frames_in=self.frames_in,
            dropped=self.dropped,
            latency_ms_median=float(np.median(lat)) if lat.size else None,
            latency_ms_p99=float(np.percentile(lat, 99)) if lat.size else None,
            map=mapping,
            receivers={s.value: r.stats.to_json() for s, r in self.receivers.items()})
