"""Giving freed heap memory back to the system (glibc's ``malloc_trim``)."""

from __future__ import annotations

import platform
import subprocess
import sys

import pytest

#: run in a fresh interpreter: a test process's heap may already hold freed pages to reuse
CHILD = """
from grassd.daemon.core.runtime.freed_memory import release_freed_memory
from grassd.rigs.peak_memory import rss_bytes
start = rss_bytes()
blocks = [bytearray(b"x" * (64 * 1024)) for _ in range(3072)]
live = blocks.pop()
del blocks
before = rss_bytes()
released = release_freed_memory()
print(released, before - start, before - rss_bytes(), len(live))
"""


@pytest.mark.skipif(platform.libc_ver()[0] != "glibc", reason="malloc_trim is glibc's")
def test_freed_blocks_below_a_live_one_are_given_back():
    """192 MiB of heap blocks freed under one still in use (so glibc cannot shrink its heap
    from the top, as after a burst of requests): resident until released, then given back."""
    out = subprocess.run([sys.executable, "-c", CHILD], capture_output=True, text=True,
                         check=True, timeout=60).stdout.split()
    released, grew, given_back = out[0], int(out[1]), int(out[2])
    assert released == "True"
    assert grew > 128 * 2**20  # freed, still resident
    assert given_back > 128 * 2**20
