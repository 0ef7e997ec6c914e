"""The content feature inside the daemon: the player on the daemon's frame output, the
calibration's colours for it, and its control-socket commands.

:class:`ContentFeature` joins it to the service (a
:class:`~grassd.daemon.core.runtime.features.Feature`): for every config with ``[content]``
enabled, a :class:`ContentPlayback` on a frame output over the fleet's lines
(:func:`start_content`), stopped before a reload closes the fleet and started again after it,
held while a measurement takes the display, and its status under ``content``. Commands::

    {"cmd": "content_frame", "levels": [n_pixels ints 0..255], "hold_s": 10}
        -> {"ok": true}      one frame (row-major from the top left) above the playlist;
                             or "levels_hex": two hex digits a pixel
    {"cmd": "content_show", "path": "/abs/picture.gif", "duration_s": 30}
        -> {"ok": true, "frames": 12}   the daemon reads the file (readable by its user)
    {"cmd": "content_stop"}  -> {"ok": true}   ends a frame or picture asked for
    {"cmd": "content_status"} -> {"ok": true, "content": {...}}   (read-only)

All but ``content_status`` change what the display shows: the control socket serves them only
for root and the daemon's own user, as every state-changing command.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import math
import threading
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike

from grassd.daemon.content.colour_map import REFERENCE_VIEWPOINT, DisplayColours
from grassd.daemon.content.pictures import load_animation
from grassd.daemon.content.player import MAX_REQUEST_S, ContentPlayer
from grassd.daemon.content.shown import SHOWN_EVERY_S, ShownDisplay
from grassd.daemon.content.sink import ClosableSink, FrameSink, StatsSink
from grassd.daemon.content.status import ContentStatus, ContentStatusJson
from grassd.daemon.core.config.settings import Config
from grassd.daemon.core.runtime.control_commands import Answer, Request
from grassd.daemon.core.runtime.features import Feature
from grassd.daemon.core.store.layout import report_stem

if TYPE_CHECKING:
    from grassd.daemon.core.monitoring.page_parts import Card, Clock
    from grassd.daemon.core.runtime.service import Service
    from grassd.daemon.core.store.history import History

log = logging.getLogger(__name__)

#: the commands the feature answers; only ``content_status`` is read-only
COMMANDS = frozenset({"content_frame", "content_show", "content_stop", "content_status"})
READ_ONLY = frozenset({"content_status"})
#: seconds between looks at which table is active (a new one brings new colours)
COLOURS_CHECK_S = 2.0


class ContentAnswer(Answer, total=False):
    """The answers of the content commands: ``content_status``'s ``content``,
    ``content_show``'s ``frames`` and ``length_s`` (the picture's, s)."""

    content: ContentStatusJson
    frames: int
    length_s: float


def colours_from_report(report: dict[str, Any], table_um: ArrayLike) -> DisplayColours | None:
    """The predicted colours of the levels of ``table_um`` (256,) [um] from a run's report:
    the Lab per length of its viewpoint nearest the reference one (170 cm, 2 m, 0 deg);
    None when the report holds no Lab (older runs, tables per controller or pixel)."""
    vps = [v for v in report.get("viewpoints") or [] if v.get("lab_d50")]
    if not vps:
        return None
    h, d, t = REFERENCE_VIEWPOINT
    vp = min(vps, key=lambda v: abs(v["h_cm"] - h) / 10 + abs(v["d_m"] - d)
             + abs(v["theta_deg"] - t) / 10)
    table_mm = np.asarray(table_um, np.float64) / 1000.0
    return DisplayColours.from_curve(
        table_mm, vp["lengths_mm"], vp["lab_d50"],
        f"run {report.get('run_id')}, viewpoint ({vp['h_cm']:g}, {vp['d_m']:g}, "
        f"{vp['theta_deg']:g})")


class ContentPlayback:
    """The player for ``cfg`` (with ``[content]``) on ``sink``; the colours come from the
    active table's run (``history``, reports in ``reports_dir``), read again when it
    changes. ``live`` False starts no receiver (a one-off show)."""

    def __init__(self, cfg: Config, sink: FrameSink, history: History, reports_dir: Path, *,
                 live: bool = True) -> None:
        assert cfg.content is not None
        self.cfg = cfg
        self.sink = sink
        self.history = history
        self.reports_dir = reports_dir
        self._colours: tuple[int | None, DisplayColours | None] = (None, None)
        self._checked_at = float("-inf")
        self._lock = threading.Lock()
        from zoneinfo import ZoneInfo

        tz = ZoneInfo(cfg.site.timezone)
        from datetime import datetime

        self.player = ContentPlayer(cfg.content, cfg.display.rows, cfg.display.cols, sink,
                                    colours=self.colours,
                                    hour=lambda: datetime.now(tz).hour, live=live)

    def colours(self) -> DisplayColours | None:
        """The active table's predicted colours (cached per table; which table is active is
        looked up at most every :data:`COLOURS_CHECK_S`)."""
        now = time.monotonic()
        with self._lock:
            if now < self._checked_at + COLOURS_CHECK_S:
                return self._colours[1]
        cur = self.history.current_table()
        run = None if cur is None else cur.id
        with self._lock:
            self._checked_at = now
            if run == self._colours[0]:
                return self._colours[1]
        colours = None
        if cur is not None:
            path = self.reports_dir / (report_stem(cur.id) + ".json")
            try:
                colours = colours_from_report(json.loads(path.read_text("utf-8")),
                                              cur.lengths_um)
            except (OSError, ValueError, KeyError, TypeError) as exc:
                log.warning("content: no colours from run %d's report %s (%s): pictures map "
                            "by luminance", cur.id, path, exc)
        with self._lock:
            self._colours = (run, colours)
        return colours

    def start(self) -> ContentPlayback:
        """Start receiving and playing."""
        self.player.start()
        return self

    def stop(self) -> None:
        """Stop receiving and playing, then close the sink when it can be closed."""
        self.player.stop()
        if isinstance(self.sink, ClosableSink):
            self.sink.close()

    def hold(self) -> None:
        """A measurement takes the display: the sink sends nothing until :meth:`release`."""
        self.sink.hold()

    def release(self) -> None:
        """The measurement gives the display back."""
        self.sink.release()

    def status(self) -> ContentStatus:
        """The player's snapshot, with the frame output's own figures when it has them."""
        st = self.player.status()
        if isinstance(self.sink, StatsSink):
            st = dataclasses.replace(st, output=self.sink.stats().to_json())
        return st

    @staticmethod
    def handles(cmd: str) -> bool:
        """Whether ``cmd`` is one of the feature's commands."""
        return cmd in COMMANDS

    def handle(self, req: Request) -> ContentAnswer:
        """Answer one of :data:`COMMANDS` (runs in a control-socket thread); a bad request
        raises ValueError naming what to send."""
        cmd = req["cmd"]
        if cmd == "content_status":
            answer: ContentAnswer = {"ok": True, "content": self.status().to_json()}
            return answer
        if cmd == "content_stop":
            self.player.stop_request()
            return {"ok": True}
        if cmd == "content_frame":
            self.player.set_frame(_frame_levels(req, self.player.n_pixels),
                                  _seconds(req, "hold_s", self.cfg.content.hold_s))
            return {"ok": True}
        if cmd == "content_show":
            path = req.get("path")
            if not isinstance(path, str) or not Path(path).is_absolute():
                raise ValueError('content_show needs "path": the absolute path of a picture '
                                 "file the daemon's user can read")
            c = self.cfg.content
            anim = load_animation(Path(path), self.cfg.display.rows, self.cfg.display.cols,
                                  c.max_picture_mib << 20)
            self.player.show(anim, _seconds(req, "duration_s", max(anim.length_s, 10.0)))
            answer = {"ok": True, "frames": len(anim.frames), "length_s": anim.length_s}
            return answer
        raise ValueError(f"unknown content command {cmd!r}")


def _frame_levels(req: Request, n: int) -> np.ndarray:
    """The ``n`` levels of a ``content_frame`` request: ``levels`` (a list of integers
    0..255) or ``levels_hex`` (two hex digits a pixel: a frame of 4096 pixels fits a request
    line); raises ValueError naming the forms."""
    levels, text = req.get("levels"), req.get("levels_hex")
    if isinstance(text, str) and levels is None and len(text) == 2 * n:
        try:
            return np.frombuffer(bytes.fromhex(text), np.uint8).copy()
        except ValueError:
            pass
    elif (isinstance(levels, list) and text is None and len(levels) == n and all(
            isinstance(v, int) and not isinstance(v, bool) and 0 <= v <= 255 for v in levels)):
        return np.asarray(levels, np.uint8)
    raise ValueError(f'content_frame needs "levels": {n} integers 0..255, or "levels_hex": '
                     f"{2 * n} hex digits (the display's pixels row by row from the top left)")


def _seconds(req: Request, key: str, default: float) -> float:
    """``req[key]`` as seconds in (0, :data:`MAX_REQUEST_S`], else ``default``."""
    v = req.get(key, default)
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v) \
            or not 0 < v <= MAX_REQUEST_S:
        raise ValueError(f'"{key}" must be a number of seconds in (0, {MAX_REQUEST_S:g}]')
    return float(v)


def start_content(cfg: Config, sink: FrameSink, history: History,
                  reports_dir: Path) -> ContentPlayback | None:
    """The started playback for ``cfg``, or None without ``[content]`` or with
    ``enabled = false``. Raises :class:`~grassd.daemon.content.receiver.ReceiverBindError`
    when a receiver cannot listen."""
    if cfg.content is None or not cfg.content.enabled:
        return None
    return ContentPlayback(cfg, sink, history, reports_dir).start()


class ContentFeature(Feature):
    """Content in the daemon (module docstring); ``playback`` the player now, None without
    ``[content]`` enabled or while a receiver could not listen."""

    name = "content"

    def __init__(self, shown_every_s: float = SHOWN_EVERY_S) -> None:
        self.playback: ContentPlayback | None = None
        self.shown_every_s = shown_every_s
        #: the display as last read for the card's picture, and when (monotonic s)
        self.last_shown: ShownDisplay | None = None
        self._shown_at = float("-inf")
        self._shown_error: str | None = None

    def pause(self, svc: Service) -> None:
        """Stop the playback and its frame output, which shares the fleet's lines."""
        self._end()

    def restart(self, svc: Service, old: Config | None) -> None:
        """Start the playback for ``svc.cfg`` on a frame output over the fleet's lines at
        ``[content] fps`` (none without ``[content]`` enabled); a receiver that cannot listen
        is logged and the daemon goes on calibrating. The status page's picture of the
        display is read through it (:meth:`card_news`)."""
        from grassd.daemon.content.frames import FrameOutput
        from grassd.daemon.content.receiver import ReceiverBindError

        self._end()
        cfg = svc.cfg
        if cfg.content is None or not cfg.content.enabled:
            return
        sink = FrameOutput(cfg.controllers, cfg.display.pixel_count, fps=float(cfg.content.fps),
                           fleet=svc.fleet)
        try:
            self.playback = start_content(cfg, sink, svc.history, svc.reports_dir)
        except ReceiverBindError as exc:
            log.error("content: %s", exc)

    def _end(self) -> None:
        if self.playback is not None:
            self.playback.stop()  # and its frame output
        self.playback = None

    def stop(self) -> None:
        """Stop the playback."""
        self._end()

    def status(self) -> ContentStatusJson | None:
        """The playback's status (:class:`~grassd.daemon.content.status.ContentStatus`)."""
        return None if self.playback is None else self.playback.status().to_json()

    def handles(self, cmd: str) -> bool:
        """One of :data:`COMMANDS` while content plays."""
        return self.playback is not None and self.playback.handles(cmd)

    def handle(self, svc: Service, req: Request) -> ContentAnswer:
        """:meth:`ContentPlayback.handle`."""
        playback = self.playback
        if playback is None:  # stopped meanwhile by a reload
            return {"ok": False, "error": "the daemon shows no content now; try again"}
        return playback.handle(req)

    def hold(self) -> None:
        """A measurement takes the display: nothing goes out until :meth:`release`."""
        if self.playback is not None:
            self.playback.hold()

    def release(self) -> None:
        """The measurement gives the display back."""
        if self.playback is not None:
            self.playback.release()

    def card(self, svc: Service, clock: Clock) -> Card | None:
        """What the display shows and its last picture
        (:func:`~grassd.daemon.content.card.content_card`); None while no content plays."""
        from grassd.daemon.content.card import content_card

        st = self.status()
        return None if st is None else content_card(st, self.last_shown, clock)

    def card_news(self, svc: Service) -> bool:
        """Read the display for the card's picture when ``shown_every_s`` has passed since
        the last reading; True when a new reading came (a reading that fails is logged once
        and the card keeps its last picture; none is taken while no content plays)."""
        now = time.monotonic()
        if self.playback is None or now - self._shown_at < self.shown_every_s:
            return False
        try:
            shown = self.shown(svc)
        except Exception as exc:  # the page is written without a new picture
            msg = f"cannot read the display's positions: {exc}"
            if msg != self._shown_error:
                log.warning("content: %s (the daemon keeps running)", msg)
                self._shown_error = msg
            return False
        self._shown_error = None
        if shown is None:  # nothing plays now: the last picture stays
            return False
        self.last_shown, self._shown_at = shown, now
        return True

    def shown(self, svc: Service) -> ShownDisplay | None:
        """The display as its controllers report it now (GET_POSITIONS through the fleet,
        :func:`~grassd.daemon.content.shown.read_shown`), for the status page's picture; None
        when no content plays (none configured, nothing showing, or held by a measurement)."""
        from grassd.daemon.content.shown import LengthColours, read_shown
        from grassd.daemon.content.status import ContentSource

        playback = self.playback
        if playback is None:
            return None
        st = playback.status()
        if st.source is ContentSource.NONE or (st.output is not None and st.output["held"]):
            return None
        colours, cur = playback.colours(), svc.history.current_table()
        palette = None if colours is None or cur is None else \
            LengthColours.from_table(cur.lengths_um, colours.level_lab)
        d = svc.cfg.display
        return read_shown(svc.fleet, svc.cfg.controllers, d.rows, d.cols, colours=palette)
