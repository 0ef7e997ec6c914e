"""What the content feature reports: the source now showing, frames in and out per second,
dropped frames, latency, and each receiver's counts (status, ``grassd status``, metrics)."""

from __future__ import annotations

import enum
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any


class ContentSource(enum.Enum):
    """Who the display's frames come from, highest priority first."""

    SACN = "sacn"
    ARTNET = "artnet"
    SCRIPT = "script"
    PLAYLIST = "playlist"
    IDLE = "idle"
    NONE = "none"


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
    output: dict[str, Any] | None = None

    def to_json(self) -> dict[str, Any]:
        """The snapshot as a JSON object (the source by its value)."""
        out = dict(self.__dict__)
        out["source"] = self.source.value
        return out



def content_line(d: Mapping[str, Any]) -> str:
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
