"""Read length-table files given to ``grassd controllers push --table FILE`` (PROTOCOL.md §6).

* ``.json``: a list of 256 integers (global table), a list of n lists of 256 (per-pixel tables),
  or ``{"lengths_um": <one of those>, "table_id": <optional u32>}``.
* anything else (``.csv``, ``.txt``): integers separated by commas and/or whitespace, one row
  of 256 per table; ``#`` starts a comment line.

Values are micrometres of green grass.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from grassd.firmware_proto.errors import TableError, TableFileError
from grassd.firmware_proto.tables import as_table_array


def load_table_file(path: str | Path) -> tuple[np.ndarray, int | None]:
    """Load a table file; return ``(table_um, table_id or None)``, table uint16 (256,)/(n, 256).

    Raises :class:`TableFileError` naming the file and what is wrong with it.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise TableFileError(f"cannot read table file {path}: {exc}") from None
    table_id = None
    if path.suffix.lower() == ".json":
        try:
            doc = json.loads(text)
        except json.JSONDecodeError as exc:
            raise TableFileError(f"{path}: not valid JSON: {exc}") from None
        if isinstance(doc, dict):
            unknown = set(doc) - {"lengths_um", "table_id"}
            if unknown or "lengths_um" not in doc:
                raise TableFileError(f"{path}: expected keys 'lengths_um' and optional "
                                     f"'table_id', got {sorted(doc)}")
            table_id = doc.get("table_id")
            if table_id is not None and (not isinstance(table_id, int)
                                         or not 0 <= table_id <= 0xFFFFFFFF):
                raise TableFileError(f"{path}: table_id must be an integer 0..4294967295, "
                                     f"got {table_id!r}")
            doc = doc["lengths_um"]
        values = doc
    else:
        rows = []
        for lineno, line in enumerate(text.splitlines(), 1):
            line = line.strip()
            if not line or line.startswith("#"):
                continue
            try:
                rows.append([int(tok) for tok in line.replace(",", " ").split()])
            except ValueError:
                raise TableFileError(f"{path}:{lineno}: not a list of integers: "
                                     f"{line[:60]!r}") from None
        if sum(len(r) for r in rows) == 256:  # a single table may be wrapped over many lines
            rows = [[v for r in rows for v in r]]
        if any(len(r) != 256 for r in rows):
            raise TableFileError(f"{path}: every row must hold 256 values (one table), got row "
                                 f"lengths {sorted({len(r) for r in rows})}")
        values = rows[0] if len(rows) == 1 else rows
    try:
        arr = np.asarray(values)
        if arr.dtype == object:
            raise TableError(f"ragged table: rows of different lengths in {path}")
        return as_table_array(arr), table_id
    except (TableError, ValueError, TypeError) as exc:
        raise TableFileError(f"{path}: {exc}") from None
