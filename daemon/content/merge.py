"""Several live senders merged into one frame, as E1.31 says, with bounded state.

Per universe, only senders heard within ``source_timeout_s`` that have not terminated their
stream count; of those, the highest priority wins (E1.31 priority 0..200; Art-Net has none,
every sender is 100). Senders of the same, highest priority are merged HTP: each channel
takes the highest level any of them sends (Art-Net's default merge, and what most sACN
nodes do; E1.31 leaves it to the receiver). A sender's packets are taken in sequence: one
whose sequence number is 0..19 behind the last one of that sender and universe is late and
dropped (E1.31 6.7.2; Art-Net sequence 0 means "not sequenced"). A stream-terminated packet
takes its sender off that universe at once.

State is bounded whatever the network sends: at most ``max_sources`` senders (a sender
beyond that is refused and counted until one times out), each holding at most the display's
universes (512 bytes each); packets for other universes are counted and dropped.
"""

from __future__ import annotations

import enum
import threading
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from grassd.daemon.content.config import UNIVERSE_CHANNELS
from grassd.daemon.content.packets import DmxPacket
from grassd.daemon.content.pixel_order import universe_slices

#: a packet this many sequence numbers behind, or fewer, is late (E1.31 6.7.2)
LATE_WINDOW = 20


class Outcome(enum.Enum):
    """What became of one packet handed to :meth:`LiveMerger.offer`."""

    ACCEPTED = "accepted"
    LATE = "late"
    NOT_OURS = "not_ours"
    REFUSED = "refused"
    TERMINATED = "terminated"


@dataclass
class _Slot:
    levels: NDArray[np.uint8]
    priority: int
    sequence: int
    seen: float


@dataclass
class _Sender:
    name: str
    seen: float
    slots: dict[int, _Slot] = field(default_factory=dict)


@dataclass(frozen=True, eq=False)
class LiveFrame:
    """The merged frame: ``levels`` (n_pixels,) uint8 in stream order, ``at`` the monotonic
    time [s] of the newest packet in it, ``senders`` the senders now counted."""

    levels: NDArray[np.uint8]
    at: float
    senders: int


class LiveMerger:
    """Merges senders' universes ``first_universe``, ``first_universe + 1``, ... into a
    stream of ``n_pixels`` channels starting at ``start_channel`` (1-based); thread-safe."""

    def __init__(self, n_pixels: int, first_universe: int, start_channel: int = 1,
                 source_timeout_s: float = 2.5, max_sources: int = 16) -> None:
        self.n_pixels = n_pixels
        self.timeout_s = source_timeout_s
        self.max_sources = max_sources
        self._slices = universe_slices(n_pixels, start_channel)
        self.universes = tuple(first_universe + i for i in range(len(self._slices)))
        self._index = {u: i for i, u in enumerate(self.universes)}
        self._senders: dict[bytes | str, _Sender] = {}
        self._lock = threading.Lock()
        self._stream = np.zeros(n_pixels, np.uint8)
        self._dirty = False
        self._at = float("-inf")
        self._live = False
        #: accepted packets of the stream's last universe: complete frames received
        self.frames_in = 0

    def offer(self, pkt: DmxPacket, now: float) -> Outcome:
        """Take one decoded packet received at monotonic ``now`` [s]."""
        if pkt.universe not in self._index:
            return Outcome.NOT_OURS
        with self._lock:
            sender = self._senders.get(pkt.source)
            if sender is None:
                if pkt.terminated:
                    return Outcome.TERMINATED
                if len(self._senders) >= self.max_sources:
                    self._forget(now)
                    if len(self._senders) >= self.max_sources:
                        return Outcome.REFUSED
                sender = self._senders[pkt.source] = _Sender(pkt.name, now)
            slot = sender.slots.get(pkt.universe)
            if slot is not None and pkt.sequence >= 0 and slot.sequence >= 0:
                behind = (slot.sequence - pkt.sequence) % 256
                if behind < LATE_WINDOW and now - slot.seen < self.timeout_s:
                    return Outcome.LATE
            sender.seen = now
            self._dirty = True
            if pkt.terminated:
                sender.slots.pop(pkt.universe, None)
                if not sender.slots:
                    del self._senders[pkt.source]
                return Outcome.TERMINATED
            if slot is None:
                slot = sender.slots[pkt.universe] = _Slot(
                    np.zeros(UNIVERSE_CHANNELS, np.uint8), pkt.priority, pkt.sequence, now)
            n = len(pkt.data)
            slot.levels[:n] = np.frombuffer(pkt.data, np.uint8)
            slot.levels[n:] = 0  # a short packet: the slots it leaves out are 0
            slot.priority, slot.sequence, slot.seen = pkt.priority, pkt.sequence, now
            self._at = now
            self._live = True
            if pkt.universe == self.universes[-1]:
                self.frames_in += 1
            return Outcome.ACCEPTED

    def _forget(self, now: float) -> None:
        """Drop senders silent for the source timeout (under the lock)."""
        for key in [k for k, s in self._senders.items() if now - s.seen >= self.timeout_s]:
            del self._senders[key]

    @property
    def senders(self) -> int:
        """Senders tracked now (at most ``max_sources``)."""
        return len(self._senders)

    def frame(self, now: float) -> LiveFrame | None:
        """The merged frame at monotonic ``now``: None before the first packet and after
        every sender terminated its stream; else the stream as merged from the senders that
        count now (a universe nobody sends any more keeps its last levels)."""
        with self._lock:
            self._forget(now)
            if not self._senders and self._dirty:
                self._live = False  # every stream terminated (or timed out)
            if not self._live:
                self._dirty = False
                return None
            if self._dirty or self._senders:
                self._merge(now)
            return LiveFrame(self._stream.copy(), self._at, len(self._senders))

    def _merge(self, now: float) -> None:
        """Recompute the stream from the senders that count (under the lock)."""
        self._dirty = False
        for u, (slots, place) in zip(self.universes, self._slices, strict=True):
            live = [s.slots[u] for s in self._senders.values()
                    if u in s.slots and now - s.slots[u].seen < self.timeout_s]
            if not live:
                continue
            top = max(s.priority for s in live)
            merged = np.max(np.stack([s.levels[slots] for s in live if s.priority == top]),
                            axis=0)
            self._stream[place] = merged
