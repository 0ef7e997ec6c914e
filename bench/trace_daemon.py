"""A benchmark's daemon under tracemalloc, to find what its resident memory grows by.

With ``GRASSD_BENCH_TRACEMALLOC=DIR`` set, :class:`bench.daemon_process.BenchDaemon` starts
``python -X tracemalloc=FRAMES -m bench.trace_daemon DIR run ...`` instead of ``grassd run
...``: the daemon as it is, plus a thread that, for every ``DIR/NAME.want`` file that appears,
writes a tracemalloc snapshot to ``DIR/NAME.snap`` and removes the request (a thread, not a
signal handler: see grassd.daemon.core.runtime.signal_relay). :func:`request_snapshot` asks for one
and waits for it. Every full (generation 2) garbage collection is logged to ``DIR/gc.log``:
seconds since start, objects collected, the collection's seconds and the RSS after it (MiB).
``GRASSD_BENCH_TRACEMALLOC_FRAMES=0`` leaves tracemalloc off (it slows the daemon about 20x)
and keeps the log. The product holds no hook of its own.

Compare two snapshots: ``python -m bench.trace_daemon diff A.snap B.snap [--top N]`` prints the
allocation sites whose live memory grew most from A to B (grouped by their tracebacks).
Memory outside Python's allocators (Taichi's own, glibc's arenas) is not traced: the RSS that
the snapshots do not explain is printed beside them by the soak.
"""

from __future__ import annotations

import gc
import os
import sys
import threading
import time
import tracemalloc
from pathlib import Path

ENV = "GRASSD_BENCH_TRACEMALLOC"  #: the directory of requests and snapshots
FRAMES = int(os.environ.get(f"{ENV}_FRAMES", "12"))  #: frames kept per traced allocation


def command(directory: str, args: list[str]) -> list[str]:
    """The command line that runs ``grassd ARGS`` under tracemalloc, serving ``directory``."""
    return [sys.executable, *(["-X", f"tracemalloc={FRAMES}"] if FRAMES else []),
            "-m", "bench.trace_daemon", directory, *args]


def request_snapshot(directory: Path, name: str, limit_s: float = 120.0) -> Path | None:
    """Ask the traced daemon serving ``directory`` for snapshot ``name``; its path once
    written, None when it did not come within ``limit_s`` seconds."""
    want, snap = directory / f"{name}.want", directory / f"{name}.snap"
    want.touch()
    t0 = time.monotonic()
    while time.monotonic() - t0 < limit_s:
        if snap.exists() and not want.exists():
            return snap
        time.sleep(0.05)
    return None


def _serve(directory: Path) -> None:
    """The snapshot thread: answer every ``*.want`` in ``directory``."""
    while True:
        for want in sorted(directory.glob("*.want")):
            snap = want.with_suffix(".snap")
            if tracemalloc.is_tracing():
                tracemalloc.take_snapshot().dump(str(snap.with_suffix(".tmp")))
                os.replace(snap.with_suffix(".tmp"), snap)
            else:
                snap.touch()
            want.unlink()
        time.sleep(0.2)


def _log_full_collections(log: Path) -> None:
    """Append a line to ``log`` after every generation-2 collection (see the module)."""
    t0 = time.monotonic()
    began = [0.0]

    def callback(phase: str, info: dict) -> None:
        if info["generation"] != 2:
            return
        if phase == "start":
            began[0] = time.monotonic()
            return
        with open("/proc/self/statm") as fh:
            rss = int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20
        with open(log, "a") as fh:
            fh.write(f"{time.monotonic() - t0:.1f} collected {info['collected']} in "
                     f"{time.monotonic() - began[0]:.3f} s, RSS {rss:.1f}\n")

    gc.callbacks.append(callback)


def diff(a: Path, b: Path, top: int = 25) -> None:
    """Print the ``top`` allocation sites whose live memory grew most from ``a`` to ``b``."""
    old, new = tracemalloc.Snapshot.load(str(a)), tracemalloc.Snapshot.load(str(b))
    filters = [tracemalloc.Filter(False, tracemalloc.__file__)]
    old, new = old.filter_traces(filters), new.filter_traces(filters)
    total = (sum(s.size for s in new.statistics("filename"))
             - sum(s.size for s in old.statistics("filename")))
    print(f"traced: {total / 2**20:+.2f} MiB from {a.name} to {b.name}")
    for stat in new.compare_to(old, "traceback")[:top]:
        print(f"{stat.size_diff / 2**10:+9.1f} KiB {stat.count_diff:+7d} blocks "
              f"(now {stat.size / 2**10:.1f} KiB)")
        for line in stat.traceback.format(limit=FRAMES)[-2 * 6:]:
            print("    " + line)


def main(argv: list[str]) -> int:
    """``DIR grassd-args...`` runs the daemon serving DIR; ``diff A B [--top N]`` compares."""
    if argv[:1] == ["diff"]:
        top = int(argv[argv.index("--top") + 1]) if "--top" in argv else 25
        diff(Path(argv[1]), Path(argv[2]), top)
        return 0
    directory = Path(argv[0])
    directory.mkdir(parents=True, exist_ok=True)
    _log_full_collections(directory / "gc.log")
    threading.Thread(target=_serve, args=(directory,), daemon=True,
                     name="bench-tracemalloc").start()
    from grassd.daemon.cli.main import main as grassd_main

    return grassd_main(args=argv[1:], prog_name="grassd")


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
