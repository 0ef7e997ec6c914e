"""What the content feature reports: the source now showing, frames in and out per second,
dropped frames, latency, and each receiver's counts (status, ``grassd status``, metrics)."""

from __future__ import annotations

import enum
from dataclasses import dataclass, field
from typing import TypedDict


class ContentSource(enum.Enum):
    """Who the display's frames come from, highest priority first."""

    SACN = "sacn"
    ARTNET = "artnet"
    SCRIPT = "script"
    PLAYLIST = "playlist"
    IDLE = "idle"
    NONE = "none"


class FrameStatsJson(TypedDict):
    """The frame output's own figures as JSON
    (:meth:`grassd.daemon.content.frames.FrameStats.to_json`)."""

    frames_offered: int
    frames_shown: int
    frames_dropped: int
    frames_resent: int
    fps_shown: float
    latency_ms_median: float | None
    latency_ms_p99: float | None
    misses: int
    held: bool


class ContentStatusJson(TypedDict):
    """A :class:`ContentStatus` as JSON: the content feature's status (``content`` of
    ``grassd status --json``, the answer to ``content_status``)."""

    source: str
    detail: str
    frames_out_per_s: float
    frames_in_per_s: float
    frames_out: int
    frames_in: int
    dropped: int
    latency_ms_median: float | None
    latency_ms_p99: float | None
    map: str
    receivers: dict[str, dict[str, int]]
    output: FrameStatsJson | None


@dataclass(frozen=True)
class ContentStatus:
    """A snapshot of the player: ``source`` showing now and ``detail`` (a file, a sender);
    ``frames_out_per_s`` offered to the controllers and ``frames_in_per_s`` received live over
    the last 2 s; ``frames_out``/``frames_in``/``dropped`` (live frames replaced by a newer
    one before they were offered) since start; ``latency_ms_median``/``latency_ms_p99``: live
    packet in to frame offered [ms] (None before the first live frame); ``map``: the colour
    mapping in effect; ``receivers``: protocol -> counts
    (:class:`~grassd.daemon.content.receiver.ReceiverStats` as JSON); ``output``: the frame
    output's own figures (frames shown, latency to the last controller's ACK; None without)."""

    source: ContentSource
    detail: str
    frames_out_per_s: float
    frames_in_per_s: float
    frames_out: int
    frames_in: int
    dropped: int
    latency_ms_median: float | None
    latency_ms_p99: float | None
    map: str
    receivers: dict[str, dict[str, int]] = field(default_factory=dict)
    output: FrameStatsJson | None = None

    def to_json(self) -> ContentStatusJson:
        """The snapshot as a JSON object (the source by its value)."""
        return {"source": self.source.value, "detail": self.detail,
                "frames_out_per_s": self.frames_out_per_s,
                "frames_in_per_s": self.frames_in_per_s, "frames_out": self.frames_out,
                "frames_in": self.frames_in, "dropped": self.dropped,
                "latency_ms_median": self.latency_ms_median,
                "latency_ms_p99": self.latency_ms_p99, "map": self.map,
                "receivers": self.receivers, "output": self.output}



def content_line(d: ContentStatusJson) -> str:
    """One line for ``grassd status`` from a :class:`ContentStatus`'s JSON form ``d``."""
    lat = ("" if d.get("latency_ms_p99") is None else
           f", latency {d['latency_ms_median']:.0f} ms median / {d['latency_ms_p99']:.0f} ms "
           "p99")
    shown = d["source"] + (f" ({d['detail']})" if d.get("detail") else "")
    drops = sum(r.get("malformed", 0) + r.get("oversized", 0)
                for r in (d.get("receivers") or {}).values())
    return (f"content: {shown}, {d['frames_out_per_s']:.1f} frames/s out, "
            f"{d['frames_in_per_s']:.1f} in, {d['dropped']} dropped{lat}; "
            f"{drops} bad packet(s); map {d['map']}")
