"""How well frames get through one serial line, and the TABLE_CHUNK size it allows.

On a noisy line a frame arrives intact with probability about ``(1 - e) ** n`` for ``n`` wire
bytes at byte error rate ``e``: at 1 % a 530-byte TABLE_CHUNK frame almost never does
(0.99 ** 530 = 0.5 %), a 64-byte one usually does (0.99 ** 90 = 40 % round trip). So the host
adapts the chunk size as ZMODEM adapts its block length: it halves the chunk after each failed
chunk (down to ``min_bytes``) and doubles it after ``grow_after`` clean chunks in a row (up to
the host's and the controller's limits). Chunks may come in any size and any order, repeats
allowed (PROTOCOL.md §4), so this needs no protocol change.

:class:`LineQuality` holds that chunk size for one port and counts what happened on the line:
every request try that was answered or not (over the last ``window`` tries, so an operator sees
a cable going bad now, not averaged over months), retransmissions, the smallest chunk reached.
"""

from __future__ import annotations

import threading
from collections import deque

#: Share of recent request tries without an answer from which a line counts as noisy: a clean
#: line loses none (a controller rebooting now and then costs a few).
NOISY_RATE = 0.02


class LineQuality:
    """Adaptive chunk size and request statistics of one serial line (thread-safe reads).

    Chunk sizes are bytes of TABLE_CHUNK data: ``max_bytes`` is the host's limit (the
    controller's ``max_chunk`` from INFO applies too), ``min_bytes`` the smallest chunk it
    shrinks to, ``grow_after`` clean chunks in a row double it; ``adaptive`` False keeps every
    chunk at the limit. ``window``: how many recent request tries the failure rate is computed
    over. The defaults live in :class:`~.client.RetryPolicy`.
    """

    def __init__(self, max_bytes: int, min_bytes: int, grow_after: int, adaptive: bool,
                 window: int = 500) -> None:
        if not 1 <= min_bytes <= max_bytes:
            raise ValueError(f"chunk sizes need 1 <= min_bytes <= max_bytes, got "
                             f"{min_bytes} and {max_bytes}")
        if grow_after < 1:
            raise ValueError(f"grow_after must be at least 1, got {grow_after}")
        self.max_bytes, self.min_bytes = max_bytes, min_bytes
        self.grow_after, self.adaptive = grow_after, adaptive
        self._lock = threading.Lock()
        self._chunk = max_bytes
        self._limit = max_bytes  #: the limit of the last transfer (host's or controller's)
        self._clean = 0
        self._recent: deque[bool] = deque(maxlen=window)
        self.tries = 0  #: request frames sent (first tries and retransmissions)
        self.failures = 0  #: tries that got no valid answer in time
        self.chunks = 0  #: TABLE_CHUNKs acknowledged
        self.shrinks = 0
        self.grows = 0
        self.smallest_chunk: int | None = None  #: smallest chunk size used so far (bytes)
        self.last_push_chunk: int | None = None  #: chunk size when the last transfer ended
        self.last_push_tries: int | None = None  #: request tries the last transfer took

    def chunk_size(self, limit: int) -> int:
        """The chunk size (bytes) to send next, within the controller's ``limit``."""
        with self._lock:
            self._limit = min(limit, self.max_bytes)
            size = self._chunk if self.adaptive else self.max_bytes
            return max(1, min(size, limit))

    def note_try(self, answered: bool) -> None:
        """Count one request try: ``answered`` False when no valid answer came in time."""
        with self._lock:
            self.tries += 1
            self.failures += not answered
            self._recent.append(answered)

    def note_chunk(self, ok: bool, size: int, tail: bool = False) -> None:
        """After a TABLE_CHUNK of ``size`` bytes was acknowledged (``ok``) or not: halve the
        chunk size on a failure (not below ``min_bytes``), double it after ``grow_after``
        clean chunks in a row (not above ``max_bytes``). ``tail``: the chunk was cut short
        by the end of the table (its size says nothing about the line)."""
        with self._lock:
            if not tail and (self.smallest_chunk is None or size < self.smallest_chunk):
                self.smallest_chunk = size
            if not self.adaptive:
                self.chunks += ok
                return
            if ok:
                self.chunks += 1
                self._clean += 1
                if self._clean >= self.grow_after and self._chunk < self.max_bytes:
                    self._chunk = min(self.max_bytes, self._chunk * 2)
                    self._clean = 0
                    self.grows += 1
                return
            self._clean = 0
            new = max(self.min_bytes, min(self._chunk, size) // 2)
            if new < self._chunk:
                self.shrinks += 1
            self._chunk = new

    def note_transfer(self, chunk: int, tries: int) -> None:
        """Record the chunk size (bytes) a transfer ended with and the tries it took."""
        with self._lock:
            self.last_push_chunk, self.last_push_tries = chunk, tries

    def noisy(self) -> bool:
        """True when at least :data:`NOISY_RATE` of the recent request tries got no answer."""
        with self._lock:
            n = len(self._recent)
            return n > 0 and self._recent.count(False) >= NOISY_RATE * n

    def snapshot(self) -> dict[str, object]:
        """Counters for status: ``chunk_bytes`` (current adaptive size), ``max_chunk_bytes``
        (the last transfer's limit: the host's, or the controller's when lower),
        ``smallest_chunk_bytes``, ``last_push_chunk_bytes``, ``last_push_tries``, ``tries``,
        ``failures``, ``recent_tries`` and ``recent_failure_rate`` (fraction of the last
        ``window`` tries without answer), ``chunks``, ``shrinks``, ``grows``."""
        with self._lock:
            recent = list(self._recent)
            return {
                "chunk_bytes": min(self._chunk if self.adaptive else self.max_bytes,
                                   self._limit),
                "max_chunk_bytes": self._limit,
                "smallest_chunk_bytes": self.smallest_chunk,
                "last_push_chunk_bytes": self.last_push_chunk,
                "last_push_tries": self.last_push_tries,
                "tries": self.tries, "failures": self.failures,
                "recent_tries": len(recent),
                "recent_failure_rate": (recent.count(False) / len(recent)) if recent else None,
                "chunks": self.chunks, "shrinks": self.shrinks, "grows": self.grows,
            }
