"""Push tables through a faulty line and check each outcome against the controller's truth.

:func:`audit_pushes` pushes fresh random tables to one simulated controller through a real
:class:`~grassd.firmware_proto.client.ControllerClient` (over a pty or a
:class:`~.loopback.LoopbackLink`) and, after every push, compares what the client reported with what
the controller holds in RAM and what a fresh boot would load from its EEPROM file. A push must end
*old or new*: reported success means the new table is active and stored; a reported failure means
the old one still is (or, when the client could not read the state back, one of the two). Anything
else is counted as corrupt (a table that is neither) or mixed (RAM and EEPROM disagree, or the
report is false). Benchmarks and tests share this one check.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from grassd.firmware_proto.client import ControllerClient
from grassd.firmware_proto.errors import PushFailed
from grassd.firmware_proto.tables import table_crc
from grassd.rigs.eeprom import active_table_in
from grassd.rigs.firmware import Controller


def booted_table(ctl: Controller) -> np.ndarray | None:
    """The table (um) ``ctl`` would load if it booted now, read from its EEPROM file afresh."""
    return active_table_in(Path(ctl.eeprom.path).read_bytes(), ctl.config.capacity)


def _same(a: np.ndarray | None, b: np.ndarray | None) -> bool:
    return a is not None and b is not None and np.array_equal(a, b)


@dataclass
class PushAudit:
    """Outcome of :func:`audit_pushes`: counts, and the wall time of every push (s)."""

    pushes: int = 0
    ok: int = 0
    failed: int = 0
    unknown: int = 0  #: failures after which the state could not be read back
    corrupt: int = 0  #: the controller holds (RAM or EEPROM) a table that is neither old nor new
    mixed: int = 0  #: RAM and EEPROM disagree, or the client's report contradicts the truth
    seconds: list[float] = field(default_factory=list)
    problems: list[str] = field(default_factory=list)  #: the first few violations, in words

    @property
    def bad(self) -> int:
        """Corrupt plus mixed outcomes: must be 0."""
        return self.corrupt + self.mixed

    def summary(self) -> str:
        """One line: pushes, successes, failures, corrupt/mixed, median and max seconds."""
        t = np.asarray(self.seconds) if self.seconds else np.zeros(1)
        return (f"{self.pushes} pushes: {self.ok} ok, {self.failed} failed ({self.unknown} "
                f"state unknown), {self.corrupt} corrupt, {self.mixed} mixed; time per push "
                f"median {np.median(t):.3f} s, max {t.max():.3f} s")


def audit_pushes(client: ControllerClient, ctl: Controller, count: int,
                 rng: np.random.Generator, first_id: int = 1,
                 shape: tuple[int, ...] = (256,)) -> PushAudit:
    """Push ``count`` random tables (uint16 um, ``shape``) with ids ``first_id``... to ``ctl``
    through ``client``; audit each outcome (module docstring). The controller must already
    hold a table (the "old" one of the first push)."""
    audit = PushAudit()
    old = booted_table(ctl)
    if old is None:
        raise ValueError("push a first table before auditing: 'old or new' needs an old one")
    address = ctl.config.address
    for i in range(count):
        new = rng.integers(0, ctl.config.max_length_um + 1, shape).astype(np.uint16)
        tid = first_id + i
        t0 = time.perf_counter()
        try:
            st = client.push_table(address, new, table_id=tid)
            reported, active = True, (st.table_id, st.table_crc)
        except PushFailed as exc:
            reported = False
            active = None if exc.active is None else (exc.active.table_id,
                                                      exc.active.table_crc)
        audit.seconds.append(time.perf_counter() - t0)
        audit.pushes += 1
        ram, rom = ctl.active_table(), booted_table(ctl)
        problem = None
        if not (_same(ram, old) or _same(ram, new)) or not (_same(rom, old) or _same(rom, new)):
            audit.corrupt += 1
            problem = "holds a table that is neither the old nor the new one"
        elif not _same(ram, rom):
            audit.mixed += 1
            problem = "RAM and EEPROM hold different tables"
        elif reported and not (_same(ram, new) and active == (tid, table_crc(new))):
            audit.mixed += 1
            problem = "reported success but the new table is not active"
        elif not reported and active is not None and active[1] != table_crc(ram):
            audit.mixed += 1
            problem = "reported failure with a wrong active table"
        if problem is not None and len(audit.problems) < 5:
            audit.problems.append(f"push {i} (table {tid}): {problem}")
        if reported:
            audit.ok += 1
        else:
            audit.failed += 1
            audit.unknown += active is None
        old = ram if ram is not None else old
    return audit
