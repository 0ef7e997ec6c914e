"""What a call costs in time and resident memory: the hostile-input tests and benchmarks
check that a hostile input is refused quickly and before it is decoded or read whole."""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Callable
from pathlib import Path


def rss_bytes() -> int:
    """This process's resident set size now (bytes; Linux /proc)."""
    with open("/proc/self/statm") as fh:
        return int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")


def proc_mib(pid: int, key: str = "VmRSS") -> float:
    """A memory figure of process ``pid`` from /proc/PID/status, in MiB: ``VmRSS`` (resident
    now) or ``VmHWM`` (peak resident since start, or since ``5`` was written to its
    clear_refs)."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith(key + ":"):
            return int(line.split()[1]) / 1024
    raise RuntimeError(f"no {key} for pid {pid}")


def peak_rss_growth(fn: Callable[[], object], every_s: float = 0.002
                    ) -> tuple[Exception | None, float, int]:
    """Run ``fn``: (the exception it raised or None, seconds it took, peak growth of this
    process's RSS in bytes over the RSS before it, sampled every ``every_s`` seconds)."""
    base = rss_bytes()
    top = [base]
    done = threading.Event()

    def sample() -> None:
        while not done.wait(every_s):
            top[0] = max(top[0], rss_bytes())

    sampler = threading.Thread(target=sample, daemon=True)
    sampler.start()
    raised = None
    t0 = time.perf_counter()
    try:
        fn()
    except Exception as exc:  # noqa: BLE001 - returned for the caller to judge
        raised = exc
    finally:
        seconds = time.perf_counter() - t0
        done.set()
        sampler.join(timeout=5)
    return raised, seconds, max(top[0], rss_bytes()) - base


def refusal_cost(fn: Callable[[], object], error: type[Exception]) -> tuple[str, float, int]:
    """(message, seconds, peak RSS growth in bytes) of ``fn``, which must raise ``error``
    (AssertionError naming what it did instead)."""
    raised, seconds, growth = peak_rss_growth(fn)
    if not isinstance(raised, error):
        raise AssertionError(f"expected {error.__name__}, got {raised!r}")
    return str(raised), seconds, growth
