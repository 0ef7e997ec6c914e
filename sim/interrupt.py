"""Stopping a renderer launch in flight from another process.

Taichi holds Python's GIL while a kernel runs, so no thread of the renderer's process can act
until a launch ends: a caller that checks for newer work between launches waits for the launch
in flight, and must keep launches short (many small launches cost time: on 2 cores, launches of
about 900 splayed camera paths kept 1.5-1.9 cores busy, whole rounds 1.9-1.96). The renderer's
kernels therefore read one word of memory that another process may write (shared memory)
before every camera path or image pixel: once the word differs from the value the launch
started with, the launch skips its remaining paths, and the renderer asks the
:class:`Interrupt` again (:meth:`Interrupt.arm`) before it tries that launch again, tracing only
the paths it skipped (so an interrupt that ends nothing loses no work). ``arm``
raises to end the run instead.

The kernels read the word atomically, so that no task keeps it in a register for its paths.
Measured: a kernel read the word written by another process within the path in flight (a
kernel of 860 ms stopped 100 ms after the write).
"""

from __future__ import annotations

import numpy as np

from grassd.sim.errors import SimError


class Interrupt:
    """A word (``int32``, shape (1,)) that another process changes to stop a launch.

    ``arm`` is called before every launch and returns the value the launch runs under; the
    launch skips its remaining paths once the word differs. This base class runs every launch
    under the word's current value (it never ends a run); a caller that supersedes work
    overrides :meth:`arm` to raise once the work is stale.
    """

    def __init__(self, word: np.ndarray) -> None:
        if word.dtype != np.int32 or word.shape != (1,) or not word.flags.c_contiguous:
            raise SimError("an interrupt word is a contiguous int32 array of shape (1,)")
        self.word = word

    def arm(self) -> int:
        """The value of the word the next launch runs under (it stops once the word differs);
        raise to end the run instead."""
        return int(self.word[0])
