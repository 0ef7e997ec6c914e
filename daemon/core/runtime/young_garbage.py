"""The cyclic garbage of one burst of work freed when the burst ends.

A matplotlib figure (a run's report plot) is a web of reference cycles that reference counting
alone never frees. Built and saved while the garbage collector runs, its objects outlive the
collector's young collections and are promoted to the oldest generation, which CPython collects
only once the objects promoted since its last pass reach a quarter of the objects it kept then.
In a daemon whose heap is large (Taichi, NumPy, matplotlib, SciPy) several runs' plots then wait
in memory at once, as many as everything else the process holds allows: the resident set's
high-water mark follows.

:func:`freed_when_done` keeps the collector from promoting anything during its block and then
collects the young generation alone: what the block built and dropped is freed at its end, at
a cost that follows the block's objects, not the heap's.
"""

from __future__ import annotations

import contextlib
import gc
from collections.abc import Iterator


@contextlib.contextmanager
def freed_when_done() -> Iterator[None]:
    """Run the block with automatic garbage collection paused, then collect generation 0:
    the reference cycles the block made and dropped are freed as it ends (an object still
    referenced, or held by an exception leaving the block, survives as usual). Only the block
    that paused the collector collects: one disabled before stays disabled and collects
    nothing, and a nested block leaves its objects to the outermost."""
    enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if enabled:
            gc.enable()
            gc.collect(0)
