"""Content frames to the controllers: :class:`FrameOutput` sends the newest frame of 8-bit
levels to every controller, at most ``fps`` frames a second, on the same serial lines as the
fleet's table pushes, reconcile and the measurement's test patterns.

Interface (what the content sources code against)::

    out = FrameOutput(cfg.controllers, n_pixels, fps=30.0, fleet=fleet)
    out.offer(levels)      # uint8, shape (n_pixels,): returns at once, latest wins
    out.stats()            # FrameStats: offered, shown, dropped, fps shown, latency
    out.hold()             # a measurement takes the display: nothing sent while held
    out.release()          # ... and gives it back: the newest frame is sent again
    out.close()

``levels[i]`` is the level of display pixel ``i`` (row-major: row 0 at the top, column 0 at
the left), which each controller's ``pixels`` ranges map onto its own pixels in order. A frame
is *shown* when every controller acknowledged it; its *latency* runs from :meth:`offer` to the
last controller's acknowledgement (milliseconds).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from grassd.daemon.config.settings import ControllerConfig


@dataclass(frozen=True)
class FrameStats:
    """Counts since the output started, and recent rates.

    ``frames_offered``: frames given to :meth:`FrameOutput.offer`; ``frames_shown``: frames
    every controller acknowledged; ``frames_dropped``: frames replaced by a newer one before
    they were sent; ``fps_shown``: frames shown per second over the last few seconds;
    ``latency_ms_median`` / ``latency_ms_p99``: offer to the last controller's
    acknowledgement over the recent shown frames (milliseconds; None before the first).
    """

    frames_offered: int = 0
    frames_shown: int = 0
    frames_dropped: int = 0
    fps_shown: float = 0.0
    latency_ms_median: float | None = None
    latency_ms_p99: float | None = None


class FrameOutput:
    """Sends the newest offered frame to every controller in ``controllers``, at most ``fps``
    frames per second (frames per second, > 0), for a display of ``n_pixels`` pixels.

    ``fleet``: the :class:`~grassd.daemon.hardware.fleet.Fleet` whose serial lines the frames
    share (its pushes and status reads take turns with the frames, see PROTOCOL.md section
    5); without one the output opens the lines itself.
    """

    def __init__(self, controllers: Sequence[ControllerConfig], n_pixels: int, *,
                 fps: float = 30.0, fleet: object | None = None) -> None:
        raise NotImplementedError

    def offer(self, levels: np.ndarray) -> None:
        """Queue ``levels`` (uint8, shape (n_pixels,)) to be shown; returns at once. A frame
        offered before the previous one was sent replaces it (counted as dropped)."""
        raise NotImplementedError

    def stats(self) -> FrameStats:
        """The counts and recent rates (:class:`FrameStats`); safe from any thread."""
        raise NotImplementedError

    def hold(self) -> None:
        """Stop sending frames (a measurement takes the display) until :meth:`release`."""
        raise NotImplementedError

    def release(self) -> None:
        """Send frames again, starting with the newest one offered."""
        raise NotImplementedError

    def close(self) -> None:
        """Stop sending and end the sender threads (the serial lines stay the fleet's)."""
        raise NotImplementedError
