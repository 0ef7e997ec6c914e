"""Benchmark: table pushes over a noisy serial line (1 % byte errors both ways), adaptive chunks.

Two parts, both with a seeded :class:`~grassd.rigs.faults.FaultInjector` and the
production :class:`~grassd.firmware_proto.client.ControllerClient`, every push audited against
the controller's RAM and EEPROM (:func:`~grassd.rigs.push_audit.audit_pushes`: old or
new table, never corrupt or mixed):

1. 10 000 pushes of a 512-byte (256-entry) table in-process
   (:class:`~grassd.rigs.loopback.LoopbackLink`: the same client, framing and firmware
   code, no pty, no waiting), with reboots and torn EEPROM writes on top of the byte errors;
   again with fixed-size chunks for comparison (fewer pushes);
2. pushes over a real pty paced at 115200 baud (8N1) with the daemon's default retry policy:
   the wall time per push that an operator would see (goal: every push within 30 s).

Run: ``python -m bench noisy_line`` or ``python bench/bench_noisy_line.py [--quick]``.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from grassd.firmware_proto.client import ControllerClient, RetryPolicy
from grassd.rigs.faults import FaultInjector, FaultPlan
from grassd.rigs.loopback import LoopbackLink
from grassd.rigs.push_audit import PushAudit, audit_pushes
from grassd.rigs.simulator import SimulatedBus, make_controllers

BAUD = 115_200
#: 1 % of the bytes damaged, in both directions: flipped, dropped or duplicated.
NOISE = {"flip": 0.004, "drop": 0.003, "duplicate": 0.003}
#: ... plus, in-process, power cuts: per request frame, and per EEPROM write.
POWER = {"reboot": 0.002, "torn_write": 0.002}
SEED = 20261125


def _first_table(client: ControllerClient, injector: FaultInjector) -> None:
    injector.enabled = False
    client.push_table(1, np.full(256, 1000, np.uint16), table_id=0)
    injector.enabled = True


def in_process(pushes: int, adaptive: bool) -> tuple[PushAudit, ControllerClient, float]:
    """``pushes`` audited pushes over a LoopbackLink; returns the audit, client, wall seconds."""
    with tempfile.TemporaryDirectory() as tmp:
        ctrls = make_controllers(tmp, [1])
        injector = FaultInjector(FaultPlan(**NOISE, **POWER), seed=SEED)
        link = LoopbackLink(ctrls, injector, baudrate=BAUD)
        # no backoff sleeps: nothing here competes for the line, and timeouts take no time
        policy = RetryPolicy(backoff_s=0.0, adaptive_chunks=adaptive)
        client = ControllerClient("loopback", policy=policy, seed=SEED, link=link)
        _first_table(client, injector)
        t0 = time.perf_counter()
        audit = audit_pushes(client, ctrls[0], pushes, np.random.default_rng(SEED), first_id=1)
        elapsed = time.perf_counter() - t0
        for c in ctrls:
            c.close()
    return audit, client, elapsed


def over_pty(pushes: int) -> tuple[PushAudit, ControllerClient]:
    """``pushes`` audited pushes over a real pty at BAUD with the default RetryPolicy."""
    with tempfile.TemporaryDirectory() as tmp:
        ctrls = make_controllers(tmp, [1])
        injector = FaultInjector(FaultPlan(**NOISE), seed=SEED)
        with SimulatedBus(ctrls, link_path=Path(tmp) / "tty", baud=BAUD, faults=injector,
                          turnaround_s=0.0002) as bus, \
                ControllerClient(bus.path, baudrate=BAUD, seed=SEED) as client:
            _first_table(client, injector)
            audit = audit_pushes(client, ctrls[0], pushes, np.random.default_rng(SEED),
                                 first_id=1)
            if bus.errors:
                raise RuntimeError(f"the simulated bus hit {bus.errors} internal errors")
    return audit, client


def _quality(client: ControllerClient) -> str:
    q = client.quality.snapshot()
    return (f"line: {q['failures']} of {q['tries']} request tries unanswered "
            f"({q['failures'] / max(q['tries'], 1):.1%}), chunk now {q['chunk_bytes']} B, "
            f"smallest {q['smallest_chunk_bytes']} B, {q['shrinks']} shrinks / "
            f"{q['grows']} grows, the last transfer took {q['last_push_tries']} tries")


def main(argv: list[str] | None = None) -> int:
    """Print the benchmark (``argv``: command-line options; None = defaults)."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer pushes")
    args = ap.parse_args([] if argv is None else argv)
    n_loop, n_fixed, n_pty = (1000, 200, 5) if args.quick else (10_000, 1000, 20)
    noise = ", ".join(f"{k} {v:.1%}" for k, v in NOISE.items())
    power = ", ".join(f"{k} {v:.1%}" for k, v in POWER.items())
    print(f"1 controller, 512-byte table; byte errors in both directions: {noise}; seed {SEED}")
    for adaptive, n in ((True, n_loop), (False, n_fixed)):
        audit, client, elapsed = in_process(n, adaptive)
        mode = "adaptive chunks" if adaptive else "fixed chunks (max_chunk 256)"
        print(f"in-process, {mode}, plus {power}: {audit.summary()}; "
              f"{elapsed:.1f} s wall")
        print(f"    {_quality(client)}")
        for p in audit.problems:
            print(f"    VIOLATION {p}")
    audit, client = over_pty(n_pty)
    print(f"real pty at {BAUD} baud, default retry policy (timeout "
          f"{client.policy.timeout_s} s), adaptive chunks: {audit.summary()}")
    print(f"    {_quality(client)}")
    for p in audit.problems:
        print(f"    VIOLATION {p}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
