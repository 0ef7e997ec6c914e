"""What the display shows now, as its controllers report it: every pixel's grass length.

:func:`read_shown` asks each controller of a fleet for its motors' positions (GET_POSITIONS,
``position_um`` per pixel, read in requests of at most 255 pixels by the protocol client) and
places them on the display's ``rows`` x ``cols`` grid through the controllers' ``pixels``
ranges (row-major display pixels). A controller that does not answer leaves its pixels
unknown (NaN) and is named in :attr:`ShownDisplay.missing`. Reading shares the lines with
content frames (each request holds the line's bus lock, PROTOCOL.md section 5), so the daemon
reads rarely: only while content plays, when it writes its status page, at most every
:data:`SHOWN_EVERY_S`.

Units: micrometres, epoch seconds.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from grassd.firmware_proto.errors import ProtocolError

#: seconds between two readings of the display for the status page, at least
SHOWN_EVERY_S = 5.0


@dataclass(frozen=True)
class MissingController:
    """A controller that did not report its positions: its ``name`` and the ``error``."""

    name: str
    error: str


@dataclass(frozen=True)
class LengthColours:
    """The colours the display is predicted to show at grass lengths: ``lengths_um`` (n,)
    increasing [um] and their D50 CIELAB ``lab`` (n, 3) (the active table's levels)."""

    lengths_um: NDArray[np.float64]
    lab: NDArray[np.float64]

    @classmethod
    def from_table(cls, table_um: NDArray, level_lab: NDArray) -> LengthColours | None:
        """From a (256,) table [um] and its levels' Lab (256, 3); None when the table is not
        one global table (per controller or pixel) or the shapes do not match."""
        table = np.asarray(table_um, np.float64)
        lab = np.asarray(level_lab, np.float64)
        if table.ndim != 1 or lab.shape != (table.size, 3) or table.size < 2:
            return None
        order = np.argsort(table, kind="stable")
        return cls(table[order], lab[order])

    def at(self, lengths_um: NDArray) -> NDArray[np.float64]:
        """D50 CIELAB (..., 3) predicted at ``lengths_um`` (...) [um], linearly interpolated
        (clamped to the table's ends)."""
        x = np.asarray(lengths_um, np.float64)
        return np.stack([np.interp(x, self.lengths_um, self.lab[:, k]) for k in range(3)],
                        axis=-1)


@dataclass(frozen=True, eq=False)
class ShownDisplay:
    """One reading of the display: ``lengths_um`` (rows, cols) where each pixel's grass stands
    [um] (its encoder's position; NaN: its controller did not answer, or no controller drives
    it) and ``targets_um`` (rows, cols) where its motor is going [um] (NaN likewise), read at
    ``read_at`` (epoch s); ``max_length_um``: the longest grass the controllers reach;
    ``answered``: the controllers that reported, ``missing``: those that did not;
    ``colours``: the lengths' predicted colours (None: draw a green scale)."""

    lengths_um: NDArray[np.float64]
    targets_um: NDArray[np.float64]
    read_at: float
    max_length_um: int
    answered: tuple[str, ...]
    missing: tuple[MissingController, ...]
    colours: LengthColours | None = None

    @property
    def rows(self) -> int:
        """The display's rows."""
        return int(self.lengths_um.shape[0])

    @property
    def cols(self) -> int:
        """The display's columns."""
        return int(self.lengths_um.shape[1])


def read_shown(fleet, controllers: Sequence, rows: int, cols: int, *,
               colours: LengthColours | None = None,
               default_max_um: int = 20_000) -> ShownDisplay:
    """Read every controller's motor positions and targets through ``fleet`` (its ``client(c)``) and
    place them on the ``rows`` x ``cols`` display by each controller's ``pixels`` ranges.
    A controller whose request fails (no answer, port gone, a refusal) is listed as missing;
    ``default_max_um`` [um] is the scale when none answers."""
    from grassd.daemon.core.calibration.display_model import controller_pixels

    n = rows * cols
    out = np.full((n, 2), np.nan)
    answered: list[str] = []
    missing: list[MissingController] = []
    max_um = 0
    for c, pix in zip(controllers, controller_pixels(controllers, n), strict=True):
        client = fleet.client(c)
        try:
            info = client.hello(c.address)
            pos = client.read_positions(c.address, 0, min(len(pix), info.n_pixels))
        except (ProtocolError, OSError) as exc:
            missing.append(MissingController(c.name, str(exc) or type(exc).__name__))
            continue
        out[pix[:len(pos)]] = pos
        max_um = max(max_um, int(info.max_length_um))
        answered.append(c.name)
    return ShownDisplay(out[:, 0].reshape(rows, cols), out[:, 1].reshape(rows, cols),
                        time.time(), max_um or default_max_um, tuple(answered),
                        tuple(missing), colours)
