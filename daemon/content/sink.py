"""Where the content's frames go: the seam with the wire side.

The player hands every frame to a :class:`FrameSink`; in the daemon that is the fleet's frame
output (:mod:`grassd.daemon.content.frames`), which sends SET_LEVEL to every controller and
latches them together. The content feature only needs these calls, so it is written and
tested against this protocol (a test captures the frames it is offered).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray

if TYPE_CHECKING:
    from grassd.daemon.content.frames import FrameStats


@runtime_checkable
class FrameSink(Protocol):
    """Takes frames of levels for the display."""

    def offer(self, levels: NDArray[np.uint8]) -> None:
        """Show ``levels``: uint8, shape (n_pixels,), display pixel index row-major (row 0
        top, column 0 left). Never blocks; a newer frame replaces one not yet sent."""

    def hold(self) -> None:
        """Stop sending frames until :meth:`release` (e.g. while a measurement has the
        display)."""

    def release(self) -> None:
        """Send frames again after :meth:`hold`."""


@runtime_checkable
class StatsSink(FrameSink, Protocol):
    """A sink that reports its own figures (frames shown, latency to the controllers' ACK)."""

    def stats(self) -> FrameStats:
        """The counts and rates (the frame output's)."""


@runtime_checkable
class ClosableSink(FrameSink, Protocol):
    """A sink the feature closes when it stops (the frame output: its sender threads)."""

    def close(self) -> None:
        """Stop sending and end the sink's threads."""
