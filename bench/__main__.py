"""Run every benchmark module (or those named on the command line: ``python -m bench sim``).

The first line names the machine (CPU model, cores, cache sizes): speed ratios move with the
CPU (grassd against Mitsuba: the same code gave forest 1.52-1.56x at one length on one 2-core
machine and 1.37-1.64x on another whose Mitsuba ran 1.8x slower), so a number is only read
beside the machine that gave it.
"""

from __future__ import annotations

import contextlib
import importlib
import os
import pkgutil
import platform
import sys
import time
from pathlib import Path


def machine_line() -> str:
    """One line naming this machine: CPU model, usable cores, per-level cache sizes (Linux
    /proc and sysfs; what is missing elsewhere is left out)."""
    model = platform.processor() or platform.machine()
    with contextlib.suppress(OSError):
        fields: dict[str, str] = {}
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if not line.strip():
                break  # the first CPU's block
            key, _, value = line.partition(":")
            fields[key.strip()] = value.strip()
        if "model name" in fields:  # a virtual CPU's name can be generic: add family / model
            model = (f"{fields['model name']} (family {fields.get('cpu family', '?')} model "
                     f"{fields.get('model', '?')})")
    caches = []
    for index in sorted(Path("/sys/devices/system/cpu/cpu0/cache").glob("index*")):
        with contextlib.suppress(OSError):
            kind = (index / "type").read_text().strip()
            if kind != "Instruction":
                caches.append(f"L{(index / 'level').read_text().strip()} "
                              f"{(index / 'size').read_text().strip()}")
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    return f"machine: {model}, {cores} cores" + (f", {' / '.join(caches)}" if caches else "")


def main(argv: list[str]) -> int:
    names = sorted(m.name for m in pkgutil.iter_modules([str(Path(__file__).parent)])
                   if m.name.startswith("bench_"))
    if argv:
        names = [n for n in names if n.removeprefix("bench_") in argv or n in argv]
    print(machine_line(), flush=True)
    for name in names:
        print(f"\n=== {name} ===", flush=True)
        t0 = time.perf_counter()
        module = importlib.import_module(f"bench.{name}")
        module.main()
        print(f"=== {name}: {time.perf_counter() - t0:.1f} s ===", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
