"""Benchmark: push a 256-entry length table to 8 controllers on one simulated 115200-baud bus.

The simulated RS-485 bus paces every byte at 10 bit times (8N1) in either direction, half
duplex, behind a real pty; the client is the production pyserial client. Prints seconds per
push (one controller) and per full update (all 8), and bytes on the wire against the table
payload, for several chunk sizes, and for per-pixel tables.

Run: ``python -m bench.bench_proto`` or ``python bench/bench_proto.py [--quick]``.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from grassd.firmware_proto.client import ControllerClient, RetryPolicy
from grassd.firmware_proto.tables import table_bytes
from grassd.rigs.simulator import SimulatedBus, make_controllers

BAUD = 115_200
CONTROLLERS = 8


def run_case(chunk: int, n_pixels: int, per_pixel: bool, rounds: int) -> dict[str, float]:
    """Push ``rounds`` distinct tables to every controller; return timing and byte counts."""
    rng = np.random.default_rng(0)
    with tempfile.TemporaryDirectory() as tmp:
        ctrls = make_controllers(tmp, range(1, CONTROLLERS + 1), n_pixels=n_pixels,
                                 max_chunk=1016)
        with SimulatedBus(ctrls, link_path=Path(tmp) / "bus", baud=BAUD,
                          turnaround_s=0.0002) as bus, \
                ControllerClient(bus.path, baudrate=BAUD,
                                 policy=RetryPolicy(chunk_bytes=chunk)) as client:
            for a in range(1, CONTROLLERS + 1):
                client.hello(a)  # INFO is cached by the client, as the daemon's would be
            shape = (n_pixels, 256) if per_pixel else (256,)
            payload = 0
            wire0 = bus.bytes_from_host + bus.bytes_to_host
            t0 = time.perf_counter()
            for _ in range(rounds):
                for a in range(1, CONTROLLERS + 1):
                    table = rng.integers(0, 20001, shape).astype(np.uint16)
                    client.push_table(a, table)
                    payload += len(table_bytes(table))
            elapsed = time.perf_counter() - t0
            wire = bus.bytes_from_host + bus.bytes_to_host - wire0
            retrans = client.retransmissions
    pushes = rounds * CONTROLLERS
    return {"s_per_push": elapsed / pushes, "s_per_update": elapsed / rounds,
            "wire_per_push": wire / pushes, "payload_per_push": payload / pushes,
            "overhead": wire / payload, "line_floor_s": payload / pushes * 10 / BAUD,
            "wire_time_s": wire / pushes * 10 / BAUD,
            "retransmissions": retrans}


def main(argv: list[str] | None = None) -> int:
    """Print the benchmark table (``argv``: command-line options; None = defaults)."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="one round per case")
    args = ap.parse_args([] if argv is None else argv)
    rounds = 1 if args.quick else 3
    cases = [(64, 16, False), (128, 16, False), (256, 16, False), (512, 16, False),
             (1016, 16, False), (256, 16, True), (1016, 16, True)]
    print(f"{CONTROLLERS} controllers on one simulated {BAUD}-baud half-duplex bus (8N1), "
          f"{rounds} round(s) each")
    print(f"{'table':>16} {'chunk':>5} {'s/push':>8} {'s/all 8':>8} {'payload B':>9} "
          f"{'wire B':>7} {'wire/payload':>12} {'wire time s':>11} {'line floor s':>12} "
          f"{'retx':>4}")
    for chunk, n_pixels, per_pixel in cases:
        r = run_case(chunk, n_pixels, per_pixel, rounds)
        name = f"{n_pixels}x256 per-pixel" if per_pixel else "256 global"
        print(f"{name:>16} {chunk:>5} {r['s_per_push']:8.4f} {r['s_per_update']:8.3f} "
              f"{r['payload_per_push']:9.0f} {r['wire_per_push']:7.0f} {r['overhead']:12.3f} "
              f"{r['wire_time_s']:11.4f} {r['line_floor_s']:12.4f} {r['retransmissions']:4d}")
    print("wire time = wire bytes at 115200 baud; line floor = payload alone; wire counts "
          "both directions, all frames (HELLO cached, GET_STATUS before and after, BEGIN, "
          "CHUNKs, COMMIT, ACKs)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
