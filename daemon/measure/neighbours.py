"""How much of what an eye sees of a pixel is its neighbours' grass.

A pixel's measurement quad, seen at a slant, is partly hidden by the blades of the pixel in
front of it: through the quad the eye sees that neighbour's grass, and the more of it the longer
the grass. A model that records every pixel with its neighbours in the model pixel's materials
(:func:`~grassd.daemon.measure.pixel_model.record_pixel_model`) gives a neighbour's faded or
enriched grass to the pixel behind it, and a fit of each pixel on its own then pulls each
pixel's gains towards its neighbours' (docs/measure.md, "The neighbours' grass").

:class:`NeighbourShares` holds, per pixel and green length, which pixels' yellow and green the
eye's rays through the pixel's quad meet first (:meth:`grassd.sim.renderer.Renderer.first_hits`,
each hit given to the pixel whose cell it stands over). A pixel's *seen* gain is then the
shares' mean of its own and its neighbours' gains: the first surface a ray meets carries most
of the light it brings (the light it meets further on is mostly the same pixel's).

Units: lengths mm; shares are fractions of the hits on a material (each row sums to 1).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

if TYPE_CHECKING:
    from grassd.sim.lighting import Lighting
    from grassd.sim.renderer import Renderer
    from grassd.sim.scene import DisplaySpec, Viewpoint

#: The rays through a quad at each length: ``SHARE_STRATA**2`` (a share's standard error
#: about 1 %).
SHARE_STRATA: int = 48
#: The neighbourhood a pixel's quad may show: the cells within one row and column of its own.
OFFSETS: tuple[tuple[int, int], ...] = tuple((dr, dc) for dr in (-1, 0, 1) for dc in (-1, 0, 1))
#: Where the pixel itself is in :data:`OFFSETS`.
OWN: int = OFFSETS.index((0, 0))
#: The materials the gains scale, in the renderer's order (yellow 0, green 1).
SCALED_MATERIALS: tuple[int, int] = (0, 1)


@dataclass(frozen=True, eq=False)
class NeighbourShares:
    """Per pixel, the share of its quad's first hits on each scaled material that stand over
    each cell of its neighbourhood.

    ``shares`` (2, N, G, 9): yellow and green; pixel; the model's grid of green lengths;
    :data:`OFFSETS`. ``index`` (N, 9): the neighbour's pixel index, -1 outside the display
    (its share 0). A pixel's row over the offsets sums to 1 (its own share 1 where a material
    was not met).
    """

    shares: NDArray[np.float64]
    index: NDArray[np.int64]

    def seen(self, gain: NDArray[np.float64], material: int, pixels: NDArray
             ) -> NDArray[np.float64]:
        """(n, G) the gains (N,) of ``material`` (0 yellow, 1 green) as the eye sees them at
        ``pixels`` (n,): the shares' mean of each pixel's own gain and its neighbours'."""
        padded = np.append(np.asarray(gain, dtype=np.float64), 1.0)  # index -1: outside
        return np.einsum("ngk,nk->ng", self.shares[material, pixels],
                         padded[self.index[pixels]])

    @classmethod
    def none(cls, n_pixels: int, n_lengths: int) -> NeighbourShares:
        """Every pixel seen as its own grass alone."""
        shares = np.zeros((2, n_pixels, n_lengths, len(OFFSETS)))
        shares[..., OWN] = 1.0
        return cls(shares, np.tile(np.arange(n_pixels)[:, None], (1, len(OFFSETS))))

    @classmethod
    def mean(cls, many: Sequence[NeighbourShares]) -> NeighbourShares:
        """The mean of shares of one display (tuft layouts averaged)."""
        return cls(np.mean([m.shares for m in many], axis=0), many[0].index)


def neighbour_index(display: DisplaySpec) -> NDArray[np.int64]:
    """(N, 9) each pixel's neighbour at each of :data:`OFFSETS` (row-major), -1 outside."""
    r, c = np.divmod(np.arange(display.rows * display.cols), display.cols)
    out = np.full((len(r), len(OFFSETS)), -1, dtype=np.int64)
    for k, (dr, dc) in enumerate(OFFSETS):
        rr, cc = r + dr, c + dc
        inside = (rr >= 0) & (rr < display.rows) & (cc >= 0) & (cc < display.cols)
        out[inside, k] = rr[inside] * display.cols + cc[inside]
    return out


def record_neighbour_shares(renderer: Renderer, display: DisplaySpec, lighting: Lighting,
                            viewpoints: Sequence[Viewpoint], grid_mm: NDArray
                            ) -> NeighbourShares:
    """The shares of every pixel of ``display`` seen from its own ``viewpoints[i]`` on
    ``grid_mm`` (mm): each first hit on a yellow or green blade is given to the cell of the
    pixel pitch it stands over (cells outside the display and beyond the neighbourhood keep
    no share; a row is normalised over the rest)."""
    grid = np.asarray(grid_mm, dtype=np.float64)
    index = neighbour_index(display)
    n = display.rows * display.cols
    pitch_m = display.pitch_mm / 1000.0
    centres = display.pixel_centres_m()
    shares = np.zeros((2, n, len(grid), len(OFFSETS)))
    for i in range(n):
        hits = renderer.first_hits(display, lighting, viewpoints[i], grid, pixel_index=i,
                                   strata=SHARE_STRATA)
        rel = np.nan_to_num((hits.xy_m - centres[i]) / pitch_m, nan=9.0)
        dc, dr = np.round(rel[..., 0]).astype(int), np.round(rel[..., 1]).astype(int)
        near = (np.abs(dr) <= 1) & (np.abs(dc) <= 1)
        slot = np.where(near, (dr + 1) * 3 + (dc + 1), 0)
        cell = slot + len(OFFSETS) * np.arange(len(grid))[:, None]  # (G, S): length, offset
        for m, material in enumerate(SCALED_MATERIALS):
            w = np.where(near & (hits.material == material), hits.weight, 0.0)
            shares[m, i] = np.bincount(cell.ravel(), weights=w.ravel(),
                                       minlength=len(grid) * len(OFFSETS)
                                       ).reshape(len(grid), len(OFFSETS))
    shares *= (index >= 0)[None, :, None, :]  # over no pixel (the frame has no blades)
    total = shares.sum(axis=-1, keepdims=True)
    empty = total[..., 0] <= 0.0
    shares = np.divide(shares, total, out=np.zeros_like(shares), where=total > 0.0)
    shares[..., OWN][empty] = 1.0
    return NeighbourShares(shares, index)
