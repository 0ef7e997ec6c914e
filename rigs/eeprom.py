"""Simulated non-volatile memory of a controller and the two-bank table store on it.

:class:`Eeprom` is a byte-addressable memory persisted to a file: every :meth:`Eeprom.write` is
one ``pwrite`` (atomic with respect to a simulated power cut) unless a *tear hook* cuts it short,
which is how a power cut in the middle of a write is simulated. A power cycle re-reads the file,
so what survives is exactly what was written.

:class:`BankStore` lays two table banks out on it (PROTOCOL.md §4): a 24-byte header with a
generation counter and CRCs, then ``capacity`` x 512 bytes of table data.
"""

from __future__ import annotations

import os
import struct
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from grassd.firmware_proto.crc import crc32_iso_hdlc
from grassd.firmware_proto.errors import SimulatorError
from grassd.firmware_proto.messages import TABLE_BYTES, TableKind
from grassd.firmware_proto.tables import table_from_bytes

#: Header magic "GRT1" read as a little-endian u32.
BANK_MAGIC = 0x31545247
_HEADER = struct.Struct("<IIIBBHI")  # magic generation table_id kind reserved n_tables data_crc
BANK_HEADER_SIZE = _HEADER.size + 4  # + header_crc


class PowerLoss(Exception):
    """Raised inside a write cut short by a simulated power failure (never leaves the simulator)."""


#: A tear hook gets (offset, data) of a write and returns how many bytes reach the memory
#: before power fails, or None to let the write complete.
TearHook = Callable[[int, bytes], "int | None"]


class Eeprom:
    """``size`` bytes of non-volatile memory kept in the file ``path`` (erased state 0xFF)."""

    def __init__(self, path: str | Path, size: int) -> None:
        self.path = Path(path)
        self.size = size
        self.tear_hook: TearHook | None = None
        self.writes = 0
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            if not self.path.exists() or self.path.stat().st_size != size:
                tmp = self.path.with_name(self.path.name + ".tmp")
                tmp.write_bytes(b"\xff" * size)
                os.replace(tmp, self.path)
            self._fd = os.open(self.path, os.O_RDWR)
        except OSError as exc:
            raise SimulatorError(f"cannot create EEPROM file {self.path}: {exc}") from None
        self._mem = bytearray()
        self.reload()

    def reload(self) -> None:
        """Re-read the memory from the file (what the chip holds after a power cycle)."""
        self._mem = bytearray(os.pread(self._fd, self.size, 0))

    def read(self, offset: int, n: int) -> bytes:
        """``n`` bytes at ``offset``."""
        return bytes(self._mem[offset:offset + n])

    def write(self, offset: int, data: bytes) -> None:
        """Write ``data`` at ``offset``; raises :class:`PowerLoss` if the tear hook cuts it."""
        if offset < 0 or offset + len(data) > self.size:
            raise ValueError(f"EEPROM write {offset}+{len(data)} outside {self.size} bytes")
        cut = self.tear_hook(offset, data) if self.tear_hook else None
        part = data if cut is None else data[:cut]
        os.pwrite(self._fd, part, offset)
        self._mem[offset:offset + len(part)] = part
        self.writes += 1
        if cut is not None:
            raise PowerLoss(f"power lost after {cut} of {len(data)} bytes at {offset}")

    def close(self) -> None:
        """Close the backing file."""
        os.close(self._fd)


@dataclass(frozen=True)
class BankHeader:
    """A bank header as stored (PROTOCOL.md §4)."""

    generation: int
    table_id: int
    kind: int
    n_tables: int
    data_crc: int

    def pack(self) -> bytes:
        """24 header bytes: fields then the CRC-32/ISO-HDLC of those fields."""
        head = _HEADER.pack(BANK_MAGIC, self.generation, self.table_id, self.kind, 0,
                            self.n_tables, self.data_crc)
        return head + struct.pack("<I", crc32_iso_hdlc(head))


class BankStore:
    """Two table banks on an :class:`Eeprom`, each holding up to ``capacity`` tables."""

    def __init__(self, eeprom: Eeprom, capacity: int) -> None:
        self.eeprom = eeprom
        self.capacity = capacity
        self.bank_size = BANK_HEADER_SIZE + capacity * TABLE_BYTES
        if eeprom.size < 2 * self.bank_size:
            raise SimulatorError(f"EEPROM of {eeprom.size} bytes cannot hold two banks of "
                                 f"{self.bank_size} bytes")

    @staticmethod
    def required_size(capacity: int) -> int:
        """EEPROM bytes needed for two banks of ``capacity`` tables."""
        return 2 * (BANK_HEADER_SIZE + capacity * TABLE_BYTES)

    def _base(self, bank: int) -> int:
        return bank * self.bank_size

    def header(self, bank: int) -> BankHeader | None:
        """The bank's header if the bank is valid (header CRC *and* data CRC check), else None."""
        raw = self.eeprom.read(self._base(bank), BANK_HEADER_SIZE)
        (crc,) = struct.unpack("<I", raw[-4:])
        if crc32_iso_hdlc(raw[:-4]) != crc:
            return None
        magic, gen, table_id, kind, _, n_tables, data_crc = _HEADER.unpack(raw[:-4])
        if magic != BANK_MAGIC or not 1 <= n_tables <= self.capacity:
            return None
        if crc32_iso_hdlc(self.read_data(bank, n_tables * TABLE_BYTES)) != data_crc:
            return None
        return BankHeader(gen, table_id, kind, n_tables, data_crc)

    def select_active(self) -> tuple[int | None, BankHeader | None]:
        """The valid bank with the largest generation (what a booting controller uses)."""
        best: tuple[int | None, BankHeader | None] = (None, None)
        for bank in (0, 1):
            h = self.header(bank)
            if h is not None and (best[1] is None or h.generation > best[1].generation):
                best = (bank, h)
        return best

    def invalidate(self, bank: int) -> None:
        """Erase the bank's magic so it can never be selected while it is being rewritten."""
        self.eeprom.write(self._base(bank), b"\xff\xff\xff\xff")

    def write_data(self, bank: int, offset: int, data: bytes) -> None:
        """Write table bytes at ``offset`` of the bank's data area."""
        self.eeprom.write(self._base(bank) + BANK_HEADER_SIZE + offset, data)

    def read_data(self, bank: int, n: int) -> bytes:
        """The first ``n`` bytes of the bank's data area."""
        return self.eeprom.read(self._base(bank) + BANK_HEADER_SIZE, n)

    def write_header(self, bank: int, header: BankHeader) -> None:
        """Write the header: the single write that makes a staged bank the active one."""
        self.eeprom.write(self._base(bank), header.pack())


class StorageImage:
    """Storage bytes read back from outside a controller (the posix firmware's file, a RAM
    dump of the QEMU image), read only, as :class:`BankStore` reads an :class:`Eeprom`."""

    def __init__(self, data: bytes) -> None:
        self.data = data
        self.size = len(data)

    def read(self, offset: int, n: int) -> bytes:
        """``n`` bytes at ``offset``."""
        return self.data[offset:offset + n]


def active_table_in(data: bytes, capacity: int) -> np.ndarray | None:
    """The table (um) a controller whose storage holds ``data`` (two banks of ``capacity``
    tables) boots with: that of the valid bank of largest generation; None without one."""
    store = BankStore(StorageImage(data), capacity)  # type: ignore[arg-type]
    bank, header = store.select_active()
    if bank is None or header is None:
        return None
    raw = store.read_data(bank, header.n_tables * TABLE_BYTES)
    return table_from_bytes(raw, header.n_tables, TableKind(header.kind))
