"""Power cut at every storage write of a table update, on the C firmware's posix port.

:func:`power_cut_sweep` stages the controller's storage with an *old* table (or none), then
for every k pushes a *new* table to a ``grassfw-posix`` process that loses power during its
k-th storage write (``--power-cut-at k:keep``: none, half or all but one of its bytes land),
restarts the firmware on the storage it
left, and records what is active: by PROTOCOL.md §4 the old or the new table, with a valid
CRC, never a mix. k runs over every write of the transfer and commit (the BEGIN's bank
invalidation, each chunk, the header switch), and one past them (no cut: the push completes).
"""

from __future__ import annotations

import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from grassd.firmware_proto.client import ControllerClient, RetryPolicy
from grassd.firmware_proto.errors import ProtocolError
from grassd.firmware_proto.tables import table_crc
from grassd.rigs.firmware import ControllerConfig
from grassd.rigs.posix_bus import EXIT_POWER_CUT, PosixBus

_QUICK = RetryPolicy(timeout_s=0.1, retries=0, restarts=0, readback_retries=0)
_PATIENT = RetryPolicy(timeout_s=0.2, retries=3, backoff_s=0.01)


@dataclass(frozen=True)
class CutOutcome:
    """What one cut left behind."""

    k: int  #: the storage write that lost power (1-based); writes + 1 = no cut
    keep: str  #: how much of that write landed: "half", "none" or "all-but-one"
    cut: bool  #: the process did lose power (else the push completed)
    active: str  #: "old", "new", "none", or "mix" (a table that is neither: a failure)
    status_crc_ok: bool  #: TABLE_STATUS's table_crc is the CRC of the table actually stored
    recovered: bool  #: pushing the new table again after the restart succeeded


def _classify(table: np.ndarray | None, old: np.ndarray | None, new: np.ndarray) -> str:
    if table is None:
        return "none"
    if table.shape == new.shape and np.array_equal(table, new):
        return "new"
    if old is not None and table.shape == old.shape and np.array_equal(table, old):
        return "old"
    return "mix"


def power_cut_sweep(workdir: str | Path, old: np.ndarray | None, new: np.ndarray, *,
                    n_pixels: int = ControllerConfig.n_pixels,
                    max_chunk: int = ControllerConfig.max_chunk,
                    keeps: tuple[str, ...] = ("half",)) -> list[CutOutcome]:
    """Sweep the power cut over every storage write of pushing ``new`` (um) over ``old``
    (um, or None for a controller that never had a table), for each way the cut write can
    be torn in ``keeps``. Returns one outcome per (keep, k), k = writes + 1 being no cut."""
    work = Path(workdir)
    base = work / "base"
    with PosixBus(base, [1], n_pixels=n_pixels, max_chunk=max_chunk) as bus:
        if old is not None:
            with ControllerClient(bus.path, policy=_PATIENT) as c:
                c.push_table(1, old, table_id=1)
        before = bus.controllers[0].eeprom.writes
        with ControllerClient(bus.path, policy=_PATIENT) as c:  # count the update's writes
            probe = bus.controllers[0].storage_path.read_bytes()
            c.push_table(1, new, table_id=2)
            writes = bus.controllers[0].eeprom.writes - before
        bus.controllers[0].storage_path.write_bytes(probe)  # back to the old table
    out = []
    for keep, k in [(keep, k) for keep in keeps for k in range(1, writes + 2)]:
        run = work / f"cut{k}-{keep}"
        shutil.copytree(base, run)
        (run / "controller-1.stats").unlink()
        bus = PosixBus(run, [1], n_pixels=n_pixels, max_chunk=max_chunk, power_cut_at=k,
                       power_cut_keep=keep).start()
        try:
            with ControllerClient(bus.path, policy=_QUICK) as c:
                try:
                    c.push_table(1, new, table_id=2)
                    cut = False
                except ProtocolError:  # the controller died mid-update: no answer
                    cut = bus.wait_exit(10) == EXIT_POWER_CUT
        finally:
            bus.stop()
        with PosixBus(run, [1], n_pixels=n_pixels, max_chunk=max_chunk) as again, \
                ControllerClient(again.path, policy=_PATIENT) as c:
            table = again.controllers[0].active_table()
            st = c.read_status(1)
            active = _classify(table, old, new)
            crc_ok = (table is None and not st.has_table) or (
                table is not None and st.has_table and st.table_crc == table_crc(table))
            try:
                recovered = c.push_table(1, new, table_id=2).table_crc == table_crc(new)
            except ProtocolError:
                recovered = False
        out.append(CutOutcome(k, keep, cut, active, crc_ok, recovered))
    return out
