"""Fault injection for the simulated serial line and controllers.

A :class:`FaultPlan` says how often each fault happens; a :class:`FaultInjector` draws them from
a seeded generator, so a test run is reproducible up to thread timing. Byte faults act on the
stream in both directions (a serial line never reorders bytes, so "delayed" means the stream
stalls before a byte); frame faults act on each request a controller receives.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class FaultPlan:
    """Probabilities of each fault (per byte, per frame or per EEPROM write) and durations (s)."""

    drop: float = 0.0  #: per byte: the byte is lost
    flip: float = 0.0  #: per byte: one random bit of it is inverted
    duplicate: float = 0.0  #: per byte: it arrives twice
    delay: float = 0.0  #: per byte: the line stalls before it for delay_s
    delay_s: tuple[float, float] = (0.005, 0.05)
    reboot: float = 0.0  #: per request frame: the controller power-cycles (before or after it)
    torn_write: float = 0.0  #: per EEPROM write: power fails part-way through the write
    unplug: float = 0.0  #: per request frame: the port disappears for unplug_s, then returns
    unplug_s: tuple[float, float] = (0.01, 0.05)

    def __post_init__(self) -> None:
        for name in ("drop", "flip", "duplicate", "delay", "reboot", "torn_write", "unplug"):
            p = getattr(self, name)
            if not 0.0 <= p <= 1.0:
                raise ValueError(f"fault probability {name} must be in [0, 1], got {p}")


@dataclass
class FaultCounts:
    """How many faults of each kind were injected."""

    dropped: int = 0
    flipped: int = 0
    duplicated: int = 0
    delayed: int = 0
    reboots: int = 0
    torn_writes: int = 0
    unplugs: int = 0

    def total(self) -> int:
        """All faults injected."""
        return (self.dropped + self.flipped + self.duplicated + self.delayed + self.reboots
                + self.torn_writes + self.unplugs)


class FaultInjector:
    """Draws the faults of ``plan`` from ``numpy.random.default_rng(seed)``.

    ``enabled`` can be cleared to let the line heal (to check that it recovers by itself).
    """

    def __init__(self, plan: FaultPlan, seed: int = 0) -> None:
        self.plan = plan
        self.rng = np.random.default_rng(seed)
        self.counts = FaultCounts()
        self.enabled = True

    def corrupt(self, data: bytes) -> list[tuple[float, bytes]]:
        """Apply byte faults to ``data``: pieces ``(stall seconds before it, bytes)`` in order."""
        p = self.plan
        if not self.enabled or not data or not (p.drop or p.flip or p.duplicate or p.delay):
            return [(0.0, data)]
        n = len(data)
        u = self.rng.random((4, n))
        drop, flip, dup, delay = (u[0] < p.drop, u[1] < p.flip, u[2] < p.duplicate,
                                  u[3] < p.delay)
        if not (drop.any() or flip.any() or dup.any() or delay.any()):
            return [(0.0, data)]
        buf = np.frombuffer(data, dtype=np.uint8).copy()
        bits = self.rng.integers(0, 8, n)
        buf[flip] ^= (1 << bits[flip]).astype(np.uint8)
        c = self.counts
        c.dropped += int(drop.sum())
        c.flipped += int((flip & ~drop).sum())
        c.duplicated += int((dup & ~drop).sum())
        c.delayed += int(delay.sum())
        repeat = np.where(drop, 0, np.where(dup, 2, 1))
        pieces: list[tuple[float, bytes]] = []
        cuts = np.flatnonzero(delay)
        bounds = [0, *cuts.tolist(), n]
        for i in range(len(bounds) - 1):
            a, b = bounds[i], bounds[i + 1]
            stall = float(self.rng.uniform(*p.delay_s)) if i > 0 else 0.0
            pieces.append((stall, np.repeat(buf[a:b], repeat[a:b]).tobytes()))
        return pieces

    def _chance(self, p: float) -> bool:
        return self.enabled and p > 0 and self.rng.random() < p

    def reboot_now(self) -> str | None:
        """Per request frame: None, or "before" / "after" handling it to power-cycle."""
        if not self._chance(self.plan.reboot):
            return None
        self.counts.reboots += 1
        return "before" if self.rng.random() < 0.5 else "after"

    def tear(self, offset: int, data: bytes) -> int | None:
        """EEPROM tear hook: bytes that get written before power fails, or None."""
        if not data or not self._chance(self.plan.torn_write):
            return None
        self.counts.torn_writes += 1
        return int(self.rng.integers(0, len(data)))

    def unplug_for(self) -> float | None:
        """Per request frame: None, or seconds the port stays gone."""
        if not self._chance(self.plan.unplug):
            return None
        self.counts.unplugs += 1
        return float(self.rng.uniform(*self.plan.unplug_s))
