"""The tables the controllers should hold: one value, validated and CRC'd once.

A run makes one display-wide table and, with ``[tables] granularity`` "controller" or "pixel",
a table of its own for each controller. :class:`DesiredTables` holds both as validated uint16
arrays (micrometres) with their CRC-32/ISO-HDLC (the CRC a controller reports), computed when
the value is made: the commit makes it from the run's result, status and reconcile read it,
and :meth:`~grassd.daemon.core.hardware.fleet.Fleet.apply` checks every controller against
its entry.

>>> import numpy as np
>>> d = DesiredTables.of(7, np.arange(256) * 10, own={"p#2": np.arange(256) * 20})
>>> d.for_controller("p#1") is d.display, d.for_controller("p#2").crc == d.own["p#2"].crc
(True, True)
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from types import MappingProxyType

import numpy as np
from numpy.typing import ArrayLike, NDArray

from grassd.firmware_proto.tables import as_table_array, table_crc


@dataclass(frozen=True, eq=False)
class CheckedTable:
    """A validated length table, (256,) or (n_pixels, 256) uint16 micrometres, and its
    CRC-32/ISO-HDLC as a controller computes it (uint16 little-endian bytes)."""

    lengths_um: NDArray[np.uint16]
    crc: int

    @classmethod
    def of(cls, lengths_um: ArrayLike) -> CheckedTable:
        """Validate ``lengths_um`` (raises :class:`~grassd.firmware_proto.errors.TableError`
        naming what is wrong) and compute its CRC."""
        arr = as_table_array(lengths_um)
        return cls(arr, table_crc(arr))

    @classmethod
    def stored(cls, lengths_um: ArrayLike, crc: int) -> CheckedTable:
        """A committed table read back from the state database with the CRC computed at its
        commit (validated as :meth:`of`; the CRC is not computed again)."""
        return cls(as_table_array(lengths_um), int(crc))


@dataclass(frozen=True, eq=False)
class DesiredTables:
    """What every controller should hold: table id ``table_id`` (the run id of the run that
    made it, ``run_id``; None for tables not from a run), each controller's own table in
    ``own`` (controller name ``port#address`` -> table) and ``display``, the table of every
    controller without one of its own (None: every controller has one)."""

    table_id: int
    display: CheckedTable | None
    own: Mapping[str, CheckedTable] = field(default_factory=lambda: MappingProxyType({}))
    run_id: int | None = None

    @classmethod
    def of(cls, table_id: int, display: ArrayLike | None,
           own: Mapping[str, ArrayLike] | None = None, *, run_id: int | None = None,
           controllers: Iterable[str] = ()) -> DesiredTables:
        """Validate and CRC the display-wide table ``display`` and every controller's own
        table in ``own`` once. ``controllers``: names that must get a table; a ValueError
        names those without one (none of their own and no ``display``)."""
        mine = {k: CheckedTable.of(v) for k, v in (own or {}).items()}
        missing = [n for n in controllers if n not in mine]
        if missing and display is None:
            raise ValueError(f"no table for controller(s) {', '.join(missing)} and no fallback")
        return cls(int(table_id), None if display is None else CheckedTable.of(display),
                   MappingProxyType(mine), run_id)

    @classmethod
    def stored(cls, table_id: int, display: CheckedTable,
               own: Mapping[str, CheckedTable], *, run_id: int) -> DesiredTables:
        """The desired tables of committed run ``run_id`` as the state database keeps them
        (:meth:`CheckedTable.stored`)."""
        return cls(int(table_id), display, MappingProxyType(dict(own)), run_id)

    def for_controller(self, name: str) -> CheckedTable:
        """The table controller ``name`` should hold: its own, else the display-wide one."""
        t = self.own.get(name, self.display)
        if t is None:
            raise ValueError(f"no table for controller {name} and no fallback")
        return t

    def own_crcs(self) -> dict[str, int]:
        """Controller name -> the CRC of its own table (empty: one table for all)."""
        return {k: t.crc for k, t in self.own.items()}

    def own_lengths(self) -> dict[str, NDArray[np.uint16]]:
        """Controller name -> its own table (uint16 micrometres; empty: one table for all)."""
        return {k: t.lengths_um for k, t in self.own.items()}
