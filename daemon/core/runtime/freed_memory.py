"""Giving freed heap memory back to the system, for processes that run for weeks.

CPython frees a large object (a decoded panorama, a burst of request buffers) to the C
library's allocator, and glibc keeps the pages resident for reuse: after a burst the resident
set stays near its peak although nothing holds it. :func:`release_freed_memory` asks glibc to
return those pages (``malloc_trim(0)``, which also gives back free pages inside its heaps, not
only at their top). Elsewhere (musl, macOS) it does nothing.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools
from collections.abc import Callable


@functools.cache
def _malloc_trim() -> Callable[[int], int] | None:
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        trim = libc.malloc_trim
    except (OSError, AttributeError):  # not glibc
        return None
    trim.argtypes = [ctypes.c_size_t]
    trim.restype = ctypes.c_int
    return trim


def release_freed_memory() -> bool:
    """Return the C heap's free pages to the system now; True when any was returned, False
    when none was or the C library cannot (not glibc). It frees nothing that is in use."""
    trim = _malloc_trim()
    return bool(trim(0)) if trim is not None else False
