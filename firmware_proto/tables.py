"""Length tables as numpy arrays and as the bytes the protocol carries (PROTOCOL.md §3).

A table maps each 8-bit level (0..255) to a green-grass length in micrometres (uint16). One
*global* table has shape (256,); *per-pixel* tables have shape (n_pixels, 256).

>>> t = np.arange(256, dtype=np.uint16) * 78
>>> len(table_bytes(t)), table_kind(t)
(512, (<TableKind.GLOBAL: 0>, 1))
>>> bool((table_from_bytes(table_bytes(t), 1) == t).all())
True
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from grassd.firmware_proto.crc import crc32_iso_hdlc
from grassd.firmware_proto.errors import TableError
from grassd.firmware_proto.messages import TABLE_BYTES, TABLE_ENTRIES, TableKind

_WIRE_DTYPE = np.dtype("<u2")


def as_table_array(table: ArrayLike) -> np.ndarray:
    """Validate a length table (micrometres) and return it as a C-contiguous uint16 array.

    Accepts shape (256,) or (n, 256) with n >= 1, integer values in 0..65535 (floats only if
    they are whole numbers). Raises :class:`TableError` naming what is wrong.
    """
    arr = np.asarray(table)
    if arr.ndim not in (1, 2) or arr.shape[-1] != TABLE_ENTRIES or arr.size == 0:
        raise TableError(f"a length table must have shape (256,) or (n_pixels, 256), "
                         f"got {arr.shape}")
    if arr.dtype.kind == "f":
        if not np.isfinite(arr).all() or (arr != np.round(arr)).any():
            raise TableError("length table holds non-integer or non-finite values; "
                             "give whole micrometres")
    elif arr.dtype.kind not in "iu":
        raise TableError(f"length table must hold integers (micrometres), got dtype {arr.dtype}")
    if arr.min() < 0 or arr.max() > 0xFFFF:
        raise TableError(f"length table values must be 0..65535 um, got {arr.min()}..{arr.max()}")
    return np.ascontiguousarray(arr, dtype=np.uint16)


def table_kind(table: np.ndarray) -> tuple[TableKind, int]:
    """``(kind, n_tables)`` of a validated table: GLOBAL for (256,), PER_PIXEL for (n, 256)."""
    if table.ndim == 1:
        return TableKind.GLOBAL, 1
    return TableKind.PER_PIXEL, int(table.shape[0])


def table_bytes(table: np.ndarray) -> bytes:
    """Wire / storage bytes of a table: 256 x u16 little-endian per table, pixel-major."""
    return np.ascontiguousarray(table, dtype=_WIRE_DTYPE).tobytes()


def table_crc(table: np.ndarray) -> int:
    """CRC-32/ISO-HDLC of :func:`table_bytes` (the ``table_crc`` of the protocol)."""
    return crc32_iso_hdlc(table_bytes(table))


def table_from_bytes(data: bytes, n_tables: int,
                     kind: TableKind = TableKind.GLOBAL) -> np.ndarray:
    """Inverse of :func:`table_bytes`: shape (256,) for GLOBAL, (n_tables, 256) for PER_PIXEL."""
    if len(data) != n_tables * TABLE_BYTES:
        raise TableError(f"{len(data)} bytes do not hold {n_tables} length tables")
    arr = np.frombuffer(data, dtype=_WIRE_DTYPE).astype(np.uint16)
    return arr if kind == TableKind.GLOBAL else arr.reshape(n_tables, TABLE_ENTRIES)


def chunk_spans(total_bytes: int, chunk: int) -> list[tuple[int, int]]:
    """``(offset, length)`` of each chunk when sending ``total_bytes`` in ``chunk``-byte pieces."""
    if chunk < 1:
        raise TableError(f"chunk size must be >= 1 byte, got {chunk}")
    return [(o, min(chunk, total_bytes - o)) for o in range(0, total_bytes, chunk)]
