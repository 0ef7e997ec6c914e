"""Benchmark: content frames on paced lines (:mod:`grassd.daemon.content.frames`).

The C posix firmware on ptys paced at 115200 baud, the daemon's fleet on the same lines:
reconcile every second (the daemon's tick) and a table push every 10 s (one 512-byte table per
controller, ``[tables] granularity = "controller"``, the default), while a source offers 60
frames a second. Prints frames per second delivered (shown: SHOW written after the
controllers acknowledged the frame's levels), latency from offer to the last controller's
ACK (median, p99), frames dropped (replaced before sent), missed controller stagings, and the
pushes' durations, for:

* an 8 x 8 display on 2 lines (2 controllers of 16 pixels each per line), at ``[content] fps``
  30 and 60 (goal: at least 30 frames a second delivered, p99 at most 50 ms on 2 cores);
* a 32 x 32 display on 8 lines (4 controllers of 32 pixels each per line), at fps 30.

No timed assertion: the figures are printed. Run: ``python -m bench frames``.
"""

from __future__ import annotations

import tempfile
import threading
import time
from contextlib import ExitStack
from pathlib import Path

import numpy as np

from grassd.daemon.content.frames import FrameOutput
from grassd.daemon.core.config.settings import ControllerConfig
from grassd.daemon.core.hardware.fleet import Fleet
from grassd.rigs.posix_bus import PosixBus

BAUD = 115_200
SOURCE_FPS = 60.0
PUSH_EVERY_S = 10.0
RECONCILE_EVERY_S = 1.0


def run(lines: int, per_line: int, pixels: int, fps: float, seconds: float) -> None:
    """One scenario: ``lines`` posix processes of ``per_line`` controllers of ``pixels``."""
    n = lines * per_line * pixels
    with tempfile.TemporaryDirectory() as tmp, ExitStack() as stack:
        root = Path(tmp)
        buses = [stack.enter_context(PosixBus(root / f"s{i}", list(range(1, per_line + 1)),
                                              n_pixels=pixels, link_path=root / f"tty{i}",
                                              baud=BAUD)) for i in range(lines)]
        ctls, first = [], 0
        for b in buses:
            for a in range(1, per_line + 1):
                ctls.append(ControllerConfig(port=b.path, baud=BAUD, address=a,
                                             pixels=((first, first + pixels - 1),)))
                first += pixels
        rng = np.random.default_rng(1)
        tables = [{c.name: np.sort(rng.integers(0, 20001, 256)).astype(np.uint16)
                   for c in ctls} for _ in range(2)]
        fleet = stack.enter_context(Fleet(ctls))
        fleet.push(tables[0], 1)
        out = stack.enter_context(FrameOutput(ctls, n, fps=fps, fleet=fleet))
        stop = threading.Event()
        pushes: list[float] = []

        def source() -> None:
            t = time.monotonic()
            while not stop.is_set():
                out.offer(rng.integers(0, 256, n).astype(np.uint8))
                t += 1.0 / SOURCE_FPS
                stop.wait(max(0.0, t - time.monotonic()))

        def daemon() -> None:  # the main loop's reconcile, and a new table now and then
            k, next_push = 0, time.monotonic() + PUSH_EVERY_S / 2
            while not stop.wait(RECONCILE_EVERY_S):
                if time.monotonic() >= next_push:
                    k += 1
                    t0 = time.monotonic()
                    fleet.push(tables[k % 2], 1 + k)
                    pushes.append(time.monotonic() - t0)
                    next_push += PUSH_EVERY_S
                else:
                    fleet.reconcile(tables[k % 2], 1 + k)

        threads = [threading.Thread(target=f, daemon=True) for f in (source, daemon)]
        for t in threads:
            t.start()
        time.sleep(1.0)  # warm: every controller answered once
        before, t0 = out.stats(), time.monotonic()
        time.sleep(seconds)
        after, dt = out.stats(), time.monotonic() - t0
        stop.set()
        for t in threads:
            t.join(30)
    rows, cols = int(np.sqrt(n)), n // int(np.sqrt(n))
    print(f"{rows} x {cols} on {lines} lines ({per_line} x {pixels} pixels each), fps {fps:g}, "
          f"{dt:.0f} s: {(after.frames_shown - before.frames_shown) / dt:.1f} frames/s "
          f"delivered, latency median {after.latency_ms_median:.1f} ms p99 "
          f"{after.latency_ms_p99:.1f} ms, dropped {after.frames_dropped - before.frames_dropped}"
          f" of {after.frames_offered - before.frames_offered} offered, missed stagings "
          f"{after.misses - before.misses}, pushes "
          f"{', '.join(f'{p:.2f}' for p in pushes) or 'none'} s", flush=True)


def main() -> None:
    run(2, 2, 16, 30.0, 25.0)
    run(2, 2, 16, 60.0, 25.0)
    run(8, 4, 32, 30.0, 25.0)


if __name__ == "__main__":
    main()
