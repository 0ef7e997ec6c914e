"""What the content feature reports: the source now showing, frames in and out per second,
dropped frames, latency, and each receiver's counts (status, ``grassd status``, metrics)."""

from __future__ import annotations

import enum
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
    the last seconds; ``frames_out``/``frames_in``/``dropped`` (live frames replaced by a newer
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

    def line(self) -> str:
        """One line for ``grassd status``."""
        lat = ("" if self.latency_ms_p99 is None else
               f", latency {self.latency_ms_median:.0f} ms median / {self.latency_ms_p99:.0f} "
               "ms p99")
        shown = self.source.value + (f" ({self.detail})" if self.detail else "")
        return (f"content: {shown}, {self.frames_out_per_s:.1f} frames/s out, "
                f"{self.frames_in_per_s:.1f} in, {self.dropped} dropped{lat}; map {self.map}")
