"""What the content tests share: a frame sink that keeps what it is offered, free UDP
ports, a [content] on 127.0.0.1, and the bound every fault test keeps to."""

from __future__ import annotations

import socket
import threading
import time
from collections.abc import Callable

import numpy as np

from grassd.daemon.content.config import ArtnetConfig, ContentConfig, SacnConfig

#: the most a fault may grow the test process's peak resident memory [MiB]
RSS_GROWTH_MIB = 16
#: the share of their rate frames must keep through a fault
RATE_KEPT = 0.9


class CapturingSink:
    """A :class:`~grassd.daemon.content.sink.FrameSink` that keeps every frame offered, with
    its monotonic time."""

    def __init__(self) -> None:
        self.frames: list[tuple[float, np.ndarray]] = []
        self.lock = threading.Lock()
        self.held = False

    def offer(self, levels: np.ndarray) -> None:
        assert levels.dtype == np.uint8 and levels.ndim == 1
        with self.lock:
            self.frames.append((time.monotonic(), levels.copy()))

    def hold(self) -> None:
        self.held = True

    def release(self) -> None:
        self.held = False

    def last(self) -> np.ndarray | None:
        with self.lock:
            return self.frames[-1][1] if self.frames else None

    def wait_for(self, pred: Callable[[np.ndarray], bool], timeout_s: float = 5.0
                 ) -> np.ndarray:
        """The first frame (from now on) for which ``pred`` holds; fails after the timeout."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            f = self.last()
            if f is not None and pred(f):
                return f
            time.sleep(0.01)
        raise AssertionError(f"no such frame within {timeout_s} s; last {self.last()}")

    def times(self, since: float) -> np.ndarray:
        with self.lock:
            return np.array([t for t, _ in self.frames if t >= since])

    def rate(self, t0: float, t1: float) -> float:
        """Frames offered per second between monotonic ``t0`` and ``t1`` [s]: the count in
        the window over the window's length (0 with none)."""
        times = self.times(t0)
        return float(np.count_nonzero(times <= t1)) / (t1 - t0)


def free_udp_port() -> int:
    """A UDP port on 127.0.0.1 nobody listens on now."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def content_config(ports: tuple[int, int], **kw) -> ContentConfig:
    """A ``[content]`` with both receivers on 127.0.0.1 at ``ports``; ``kw`` replaces
    fields (``sacn_*`` / ``artnet_*`` go to the receivers)."""
    sacn = {k[5:]: v for k, v in kw.items() if k.startswith("sacn_")}
    artnet = {k[7:]: v for k, v in kw.items() if k.startswith("artnet_")}
    rest = {k: v for k, v in kw.items() if not k.startswith(("sacn_", "artnet_"))}
    return ContentConfig(enabled=True, sacn=SacnConfig(port=ports[0], **sacn),
                         artnet=ArtnetConfig(port=ports[1], **artnet), **rest)
