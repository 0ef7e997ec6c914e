"""Test patterns on the display's controllers: every pixel at a raw length, then content again.

A :class:`PatternSession` drives the controllers of a
:class:`~grassd.daemon.core.hardware.fleet.Fleet` through the protocol's PATTERN / PATTERN_END
messages (PROTOCOL.md): each pixel goes to the length asked, bypassing the active table, until the
session ends. Leaving the session, however that happens (an error, a stop request, ^C), sends
PATTERN_END to every controller; and a controller whose host died on the way returns to content by
itself when its watchdog (``timeout_s``, re-armed by every pattern) runs out. A controller in
pattern mode loses it on a power cut: it boots showing content.

A pattern is only taken as shown once every pixel's motor target equals the length asked and its
position is within ``tolerance_um`` of it (GET_POSITIONS), before and after each photo: a
controller whose pixels moved away meanwhile (it rebooted and was sent content, its watchdog ran
out) is caught, and the photo refused. One that rebooted while its motors held the pattern's
lengths still shows them: its photo stands, and the next pattern is sent to it again.

Units: lengths mm at the interface, micrometres on the wire; seconds.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Iterable, Sequence
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from grassd.daemon.core.errors import DaemonError

if TYPE_CHECKING:
    from grassd.daemon.core.config.settings import ControllerConfig
    from grassd.daemon.core.hardware.fleet import Fleet

log = logging.getLogger(__name__)


class PatternError(DaemonError):
    """A test pattern could not be shown (the message says which controller and why)."""


class PatternsUnsupported(PatternError):
    """A controller's firmware has no test patterns (update it to a version whose INFO
    announces them)."""


class PatternSession:
    """Test patterns on ``controllers`` (their ``pixels`` ranges map display pixels, row-major,
    to each controller's pixels) through ``fleet``. Use as a context manager."""

    def __init__(self, fleet: Fleet, controllers: Sequence[ControllerConfig], n_pixels: int, *,
                 timeout_s: float, settle_s: float, tolerance_um: int = 150,
                 stop: Callable[[], bool] | None = None) -> None:
        from grassd.daemon.core.calibration.display_model import controller_pixels

        self.fleet, self.controllers = fleet, tuple(controllers)
        self.pixels = controller_pixels(self.controllers, n_pixels)
        self.n_pixels = n_pixels
        self.timeout_s, self.settle_s, self.tolerance_um = timeout_s, settle_s, tolerance_um
        self.stop = stop or (lambda: False)
        self.shown: NDArray[np.int64] | None = None

    def __enter__(self) -> PatternSession:
        for c in self.controllers:
            info = self.fleet.client(c).hello(c.address)
            if not getattr(info, "supports_patterns", False):
                raise PatternsUnsupported(
                    f"controller {c.name} (firmware {info.firmware_version}) has no test "
                    "patterns; update its firmware before measuring the display")
        return self

    def __exit__(self, *exc: object) -> None:
        self.end()

    def show(self, lengths_mm: NDArray | float) -> None:
        """Drive every pixel to ``lengths_mm`` ((N,) or one value, mm) and wait until the
        motors are there (:class:`PatternError` after ``settle_s``); a controller that
        rebooted on the way is sent the pattern again. The pattern is then sent once more, so
        that the controllers' watchdog counts from the photo, not from the start of the
        motors' travel."""
        um = np.rint(np.broadcast_to(np.asarray(lengths_mm, dtype=np.float64) * 1000.0,
                                     (self.n_pixels,))).astype(np.int64)
        self.shown = um
        self._send(um, range(len(self.controllers)))
        self._settle(before_photo=True)
        self._send(um, range(len(self.controllers)))  # the same targets, the watchdog re-armed

    def wait_shown(self) -> None:
        """After a photo: check that every pixel is still within tolerance of the pattern.
        A controller that rebooted while its motors held the pattern's lengths still shows
        them: the photo stands and it is sent the pattern again. Raises
        :class:`PatternError` when a controller's pixels moved away (it rebooted and was sent
        content, or its watchdog ran out): the photo does not show the pattern."""
        self._settle(before_photo=False)

    def _send(self, um: NDArray[np.int64], which: Iterable[int]) -> None:
        for k in which:
            c = self.controllers[k]
            self.fleet.client(c).show_pattern(c.address, um[self.pixels[k]].tolist(),
                                              timeout_s=self.timeout_s)

    def _settle(self, *, before_photo: bool) -> None:
        """Wait until every pixel's target is the pattern and its position within tolerance
        (module docstring); ``before_photo``: a controller whose pixels left the pattern is
        sent it again and waited for, rather than refused."""
        if self.shown is None:
            raise PatternError("no pattern was shown")
        deadline = time.monotonic() + self.settle_s
        while True:
            held, moved, far = self._state()
            if held or (moved and before_photo):
                names = ", ".join(self.controllers[k].name for k in (*held, *moved))
                log.warning("controller(s) %s left the test pattern (rebooted or timed out); "
                            "the pattern is shown again", names)
                self._send(self.shown, (*held, *moved))
            elif moved:
                raise PatternError(
                    f"controller(s) {', '.join(self.controllers[k].name for k in moved)} "
                    "left the test pattern during the photo (rebooted or timed out) and their "
                    "pixels moved; the photo is refused")
            elif not far:
                return
            if time.monotonic() > deadline or self.stop():
                stuck = ", ".join(self.controllers[k].name for k in (*far, *moved, *held))
                raise PatternError(f"pixels of {stuck} did not reach the pattern in "
                                   f"{self.settle_s:g} s; check the motors")
            time.sleep(0.05)

    def _state(self) -> tuple[list[int], list[int], list[int]]:
        """Indices of the controllers whose targets are no longer the pattern while their
        pixels are within tolerance of it (held), of those whose targets are not the pattern
        and some pixels are not (moved), and of those on the pattern not there yet (far)."""
        held: list[int] = []
        moved: list[int] = []
        far: list[int] = []
        for k, (c, pix) in enumerate(zip(self.controllers, self.pixels, strict=True)):
            pos = self.fleet.client(c).read_positions(c.address, 0, len(pix))
            want = self.shown[pix]
            near = bool(np.all(np.abs(pos[:, 0].astype(np.int64) - want) <= self.tolerance_um))
            if np.any(pos[:, 1] != want):
                (held if near else moved).append(k)
            elif not near:
                far.append(k)
        return held, moved, far

    def end(self) -> list[str]:
        """PATTERN_END to every controller (each tried, failures logged): the display shows
        content again. Returns the controllers that did not acknowledge (their watchdog ends
        the pattern within ``timeout_s``)."""
        failed = []
        for c in self.controllers:
            try:
                self.fleet.client(c).end_pattern(c.address)
            except Exception as exc:  # every controller must be tried
                log.warning("controller %s: PATTERN_END failed (%s); its watchdog ends the "
                            "pattern within %g s", c.name, exc, self.timeout_s)
                failed.append(c.name)
        self.shown = None
        return failed
