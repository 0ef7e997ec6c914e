"""An animation's levels under the calibration's colours, mapped off the player's thread.

Mapping a picture by the nearest predicted colour costs about 0.16 ms per distinct colour
(CIEDE2000 against all 256 levels): a photograph's animation can take seconds. A
:class:`MappedAnimation` answers at once: the levels for the colours asked for when they are
mapped, else those of the colours mapped before, else the picture's luminance (instant);
meanwhile a thread of its own maps for the colours asked for, and the next frames use them.
"""

from __future__ import annotations

import logging
import threading

import numpy as np
from numpy.typing import NDArray

from grassd.daemon.content.colour_map import DisplayColours, levels_for_picture
from grassd.daemon.content.pictures import Animation

log = logging.getLogger(__name__)


class MappedAnimation:
    """``anim``'s frames as levels (n_frames, n_pixels) by ``mode`` and ``normalise``
    (:func:`~grassd.daemon.content.colour_map.levels_for_picture`)."""

    def __init__(self, anim: Animation, mode: str, normalise: str = "none") -> None:
        self.anim, self.mode, self.normalise = anim, mode, normalise
        self._lock = threading.Lock()
        self._levels: NDArray[np.uint8] | None = None
        self._for: DisplayColours | None = None
        self._busy = False

    def _map(self, colours: DisplayColours | None) -> NDArray[np.uint8]:
        return levels_for_picture(self.anim.frames, self.mode, colours,
                                  self.normalise).reshape(len(self.anim.frames), -1)

    def levels(self, colours: DisplayColours | None) -> NDArray[np.uint8]:
        """The levels for ``colours`` if mapped, else the best there is now (see the module
        docstring); never waits for a CIEDE2000 mapping."""
        with self._lock:
            if self._levels is not None and self._for is colours:
                return self._levels
            cheap = self.mode != "nearest_de00" or colours is None
            if cheap:  # luminance or green: instant
                self._levels, self._for = self._map(colours), colours
                return self._levels
            if not self._busy:
                self._busy = True
                threading.Thread(target=self._background, args=(colours,),
                                 name="content-mapping", daemon=True).start()
            if self._levels is None:
                self._levels = levels_for_picture(self.anim.frames, "luminance").reshape(
                    len(self.anim.frames), -1)
            return self._levels

    def _background(self, colours: DisplayColours) -> None:
        try:
            levels = self._map(colours)
        except Exception:  # a bug must not stop the display: the levels shown stay
            log.exception("content: mapping %s failed", self.anim.name)
            with self._lock:
                self._busy = False
            return
        with self._lock:
            self._levels, self._for, self._busy = levels, colours, False

    def wait(self, colours: DisplayColours | None, timeout_s: float) -> bool:
        """Map for ``colours`` now and wait up to ``timeout_s`` s for it (``grassd show``,
        tests); whether the levels are those of ``colours``."""
        import time

        deadline = time.monotonic() + timeout_s
        while True:
            self.levels(colours)
            with self._lock:
                if self._for is colours and self._levels is not None:
                    return True
            if time.monotonic() >= deadline:
                return False
            time.sleep(0.01)
