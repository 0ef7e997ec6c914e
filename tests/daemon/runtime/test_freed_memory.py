"""Giving freed heap memory back to the system (glibc's ``malloc_trim``)."""

from __future__ import annotations

import platform

import pytest

from grassd.daemon.core.runtime.freed_memory import release_freed_memory
from grassd.rigs.peak_memory import rss_bytes


@pytest.mark.skipif(platform.libc_ver()[0] != "glibc", reason="malloc_trim is glibc's")
def test_freed_blocks_below_a_live_one_are_given_back():
    """192 MiB of heap blocks freed under one still in use (so glibc cannot shrink its heap
    from the top, as after a burst of requests): resident until released, then given back."""
    start = rss_bytes()
    blocks = [bytearray(b"x" * (64 * 1024)) for _ in range(3072)]
    live = blocks.pop()
    del blocks
    before = rss_bytes()
    assert before - start > 128 * 2**20  # freed, still resident
    assert release_freed_memory()
    assert before - rss_bytes() > 128 * 2**20
    assert len(live) == 64 * 1024
