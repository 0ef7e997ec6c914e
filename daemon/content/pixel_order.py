"""Where the live channels go on the display: the channel stream (the first universe's start
channel, then on through the next universes) laid over the display's pixels by the
``[content]`` pixel order.

The k-th channel of the stream lands on one display pixel; display pixels are indexed
row-major from the top-left (row 0 top, column 0 left), as the frames the controllers get.
``order = "rows"`` fills a row before the next, ``"columns"`` a column; ``serpentine`` runs
every second row (column) backwards; ``first`` is the corner the stream starts in.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from grassd.daemon.content.config import UNIVERSE_CHANNELS


def stream_to_display(rows: int, cols: int, order: str = "rows", serpentine: bool = False,
                      first: str = "top-left") -> NDArray[np.int64]:
    """(rows * cols,) the display pixel index (row-major from the top-left) of each channel
    of the stream, for the pixel order given (see the module docstring)."""
    k = np.arange(rows * cols)
    if order == "rows":
        r, c = k // cols, k % cols
        if serpentine:
            c = np.where(r % 2 == 1, cols - 1 - c, c)
    elif order == "columns":
        c, r = k // rows, k % rows
        if serpentine:
            r = np.where(c % 2 == 1, rows - 1 - r, r)
    else:
        raise ValueError(f"order must be 'rows' or 'columns', not {order!r}")
    if first.endswith("right"):
        c = cols - 1 - c
    if first.startswith("bottom"):
        r = rows - 1 - r
    return (r * cols + c).astype(np.int64)


def universes_needed(n_pixels: int, start_channel: int) -> int:
    """How many consecutive universes ``n_pixels`` channels span from ``start_channel``
    (1-based) of the first one."""
    return (start_channel - 1 + n_pixels + UNIVERSE_CHANNELS - 1) // UNIVERSE_CHANNELS


def universe_slices(n_pixels: int, start_channel: int
                    ) -> list[tuple[slice, slice]]:
    """Per universe (in order): (its slots that carry pixels, their place in the stream)."""
    out = []
    k = 0
    offset = start_channel - 1
    while k < n_pixels:
        take = min(UNIVERSE_CHANNELS - offset, n_pixels - k)
        out.append((slice(offset, offset + take), slice(k, k + take)))
        k += take
        offset = 0
    return out
