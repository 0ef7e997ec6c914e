"""Hemisphere-aware importance sampling of an equirectangular environment (numpy side).

Next-event estimation at a surface only gains from light in front of it: a sampler that
ignores the surface normal wastes every sample that lands behind the surface (most of them on
the near-vertical blades: docs/renderer/measurements.md) and weights the rest without the
cosine. This sampler keeps one discrete distribution per *normal bin* and samples the map
in two levels:

1. **Coarse texel**, chosen per normal bin. The map is cut into ``cr x cc`` blocks of texels;
   block ``c`` gets weight ``W_c * max(0, cos(max(0, gamma - delta_b - r_c)))``, where ``W_c`` is
   the block's luminance x solid angle, ``gamma`` the angle between the bin's centre normal and
   the block's centre direction, ``delta_b`` the bin's angular radius and ``r_c`` the block's.
   The factor is an upper bound of ``cos(n, w)`` over every normal ``n`` in the bin and every
   direction ``w`` in the block, so a block is given zero probability only where no normal of
   the bin can receive light from it: the estimator stays unbiased, and it is close to
   cosine-weighted.
2. **Fine texel inside the block**, in proportion to luminance x solid angle (plus the usual
   small floor), the same for every bin; then uniformly in solid angle inside that texel.

The density of the whole procedure for direction ``w`` and bin ``b`` is
``P_b(block) * P(texel | block) / Omega_texel`` (piecewise constant per texel), which
:func:`binned_pdf` evaluates and the renderer's MIS uses. Normal bins: the octahedral map
(Engelhardt & Dachsbacher 2008) of the unit normal on an ``NB x NB`` grid.

Conventions as in :mod:`grassd.sim.lighting`: ``u = atan2(y, x) / 2 pi``, ``v = acos(z) / pi``,
rows from the zenith down; all tables float32 so the kernel and numpy agree.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from grassd.sim.hdri import REC709_LUMINANCE
from grassd.sim.lighting import (
    ENV_SAMPLING_FLOOR,
    direction_to_uv,
    texel_solid_angles,
    uv_to_direction,
)

NORMAL_BINS_SIDE = 12  # NB: normal bins on the octahedral map (144 bins)
COARSE_ROWS_MAX = 32
COARSE_COLS_MAX = 64


def octahedral_encode(n: np.ndarray) -> np.ndarray:
    """(..., 3) unit vectors -> (..., 2) octahedral coordinates in [0, 1]^2."""
    n = np.asarray(n, np.float64)
    p = n / np.sum(np.abs(n), axis=-1, keepdims=True)
    x, y, z = p[..., 0], p[..., 1], p[..., 2]
    fx = np.where(z < 0, (1 - np.abs(y)) * np.where(x >= 0, 1.0, -1.0), x)
    fy = np.where(z < 0, (1 - np.abs(x)) * np.where(y >= 0, 1.0, -1.0), y)
    return np.stack([fx, fy], axis=-1) * 0.5 + 0.5


def octahedral_decode(uv: np.ndarray) -> np.ndarray:
    """(..., 2) octahedral coordinates in [0, 1]^2 -> (..., 3) unit vectors."""
    f = np.asarray(uv, np.float64) * 2.0 - 1.0
    x, y = f[..., 0], f[..., 1]
    z = 1.0 - np.abs(x) - np.abs(y)
    t = np.maximum(-z, 0.0)
    x = x - np.where(x >= 0, t, -t)
    y = y - np.where(y >= 0, t, -t)
    v = np.stack([x, y, z], axis=-1)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def normal_bin(n: np.ndarray, side: int = NORMAL_BINS_SIDE) -> np.ndarray:
    """Bin index (row-major on the ``side x side`` octahedral grid) of (..., 3) unit normals."""
    uv = octahedral_encode(n)
    ij = np.minimum((uv * side).astype(np.int64), side - 1)
    return ij[..., 0] * side + ij[..., 1]


def _bin_cones(side: int) -> tuple[np.ndarray, np.ndarray]:
    """Centre normal (B, 3) and angular radius (B,) in radians of every normal bin."""
    k = 17
    t = (np.arange(side)[:, None] + np.linspace(0.0, 1.0, k)[None, :]) / side  # (side, k)
    uu = t[:, None, :, None]
    vv = t[None, :, None, :]
    uv = np.stack(np.broadcast_arrays(uu, vv), axis=-1)  # (side, side, k, k, 2)
    dirs = octahedral_decode(uv).reshape(side * side, k * k, 3)
    centre = dirs.mean(axis=1)
    centre /= np.linalg.norm(centre, axis=1, keepdims=True)
    cosines = np.clip(np.einsum("bkd,bd->bk", dirs, centre), -1.0, 1.0)
    return centre, np.arccos(cosines.min(axis=1)) + 0.02


def _largest_divisor(n: int, limit: int) -> int:
    return max(d for d in range(1, min(n, limit) + 1) if n % d == 0)


@dataclass(frozen=True)
class BinnedSampler:
    """Tables of the two-level, normal-binned environment sampler (float32, C-contiguous).

    ``bin_marginal`` (B, cr + 1): per normal bin, the CDF over block rows.
    ``bin_conditional`` (B, cr, cc + 1): per bin and block row, the CDF over block columns.
    ``block_cdf`` (cr * cc, bh * bw + 1): per block, the CDF over its texels (row-major).
    ``cos_theta_edges`` (H + 1,): ``cos(pi i / H)``. ``shape``: (H, W, cr, cc).
    """

    bin_marginal: np.ndarray
    bin_conditional: np.ndarray
    block_cdf: np.ndarray
    cos_theta_edges: np.ndarray
    shape: tuple[int, int, int, int]

    @property
    def block_shape(self) -> tuple[int, int]:
        """(bh, bw): texel rows and columns per block."""
        h, w, cr, cc = self.shape
        return h // cr, w // cc


def _cdf32(weights: np.ndarray) -> np.ndarray:
    """Row-wise CDFs (..., n + 1) in float32 with exact 0 and 1 ends (uniform for all-zero)."""
    w = np.asarray(weights, np.float64)
    total = w.sum(axis=-1, keepdims=True)
    n = w.shape[-1]
    w = np.where(total > 0, w, 1.0)
    total = np.where(total > 0, total, n)
    cdf = np.concatenate([np.zeros(w.shape[:-1] + (1,)), np.cumsum(w, axis=-1)], axis=-1) / total
    out = cdf.astype(np.float32)
    out[..., 0], out[..., -1] = 0.0, 1.0
    return np.ascontiguousarray(out)


def build_binned_sampler(env: np.ndarray, side: int = NORMAL_BINS_SIDE,
                         floor: float = ENV_SAMPLING_FLOOR) -> BinnedSampler:
    """Build the :class:`BinnedSampler` of an (H, W, 3) linear radiance map.

    Blocks: ``cr`` = the largest divisor of H up to 32, ``cc`` the largest divisor of W up to 64
    (a 2:1 map of 512 x 1024 gets 32 x 64 blocks of 16 x 16 texels). Texel weight
    ``(max(Y, 0) + floor * Y_mean) * Omega`` (:mod:`grassd.sim.lighting`, Importance sampling).
    """
    rad = np.asarray(env, np.float64)
    h, w = rad.shape[:2]
    cr, cc = _largest_divisor(h, COARSE_ROWS_MAX), _largest_divisor(w, COARSE_COLS_MAX)
    bh, bw = h // cr, w // cc
    omega = texel_solid_angles(h, w)[:, None]
    lum = np.maximum(rad @ REC709_LUMINANCE, 0.0)
    mean_y = float((lum * omega).sum() / (4.0 * np.pi))
    weight = (lum + (floor * mean_y if mean_y > 0.0 else 1.0)) * omega  # (h, w)
    blocks = weight.reshape(cr, bh, cc, bw).transpose(0, 2, 1, 3).reshape(cr * cc, bh * bw)
    block_w = blocks.sum(axis=1).reshape(cr, cc)

    # Angular radius of each block about its centre direction (boundary points + poles).
    i, j = np.meshgrid(np.arange(cr), np.arange(cc), indexing="ij")
    centre = uv_to_direction((j + 0.5) / cc, (i + 0.5) / cr)  # (cr, cc, 3)
    s = np.linspace(0.0, 1.0, 9)
    edge_u = np.concatenate([s, np.ones(9), s[::-1], np.zeros(9)])
    edge_v = np.concatenate([np.zeros(9), s, np.ones(9), s[::-1]])
    pts = uv_to_direction(*np.broadcast_arrays((j[..., None] + edge_u) / cc,
                                               (i[..., None] + edge_v) / cr))
    cos_r = np.einsum("rcpd,rcd->rcp", pts, centre).min(axis=2)
    r_block = np.arccos(np.clip(cos_r, -1.0, 1.0)) + 0.01  # (cr, cc)

    bin_centre, delta = _bin_cones(side)
    gamma = np.arccos(np.clip(np.einsum("bd,rcd->brc", bin_centre, centre), -1.0, 1.0))
    slack = np.maximum(gamma - delta[:, None, None] - r_block[None], 0.0)
    factor = np.where(slack < np.pi / 2, np.cos(np.minimum(slack, np.pi / 2)), 0.0)
    bw_bin = block_w[None] * factor  # (B, cr, cc)

    return BinnedSampler(
        bin_marginal=_cdf32(bw_bin.sum(axis=2)),
        bin_conditional=_cdf32(bw_bin),
        block_cdf=_cdf32(blocks),
        cos_theta_edges=np.cos(np.pi * np.arange(h + 1) / h).astype(np.float32),
        shape=(h, w, cr, cc),
    )


def _probabilities(s: BinnedSampler, bins: np.ndarray, row: np.ndarray, col: np.ndarray
                   ) -> np.ndarray:
    """Probability of choosing texel (row, col) under normal bin ``bins`` (float64)."""
    bh, bw = s.block_shape
    cc = s.shape[3]
    i, j = row // bh, col // bw
    k = (row % bh) * bw + col % bw
    m = s.bin_marginal.astype(np.float64)
    c = s.bin_conditional.astype(np.float64)
    f = s.block_cdf.astype(np.float64)
    block = i * cc + j
    return ((m[bins, i + 1] - m[bins, i]) * (c[bins, i, j + 1] - c[bins, i, j])
            * (f[block, k + 1] - f[block, k]))


def binned_pdf(s: BinnedSampler, bins: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """Solid-angle density (1/sr) of :func:`sample_binned` for normal bin(s) ``bins``."""
    h, w = s.shape[:2]
    u, v = direction_to_uv(directions)
    row = np.minimum((v * h).astype(np.int64), h - 1)
    col = np.minimum((u * w).astype(np.int64), w - 1)
    return _probabilities(s, np.asarray(bins), row, col) / texel_solid_angles(h, w)[row]


def _invert(cdf: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Index k with cdf[k] <= u < cdf[k + 1] per row of ``cdf`` (..., n + 1), and the residual
    (u - cdf[k]) / (cdf[k + 1] - cdf[k]) in [0, 1)."""
    n = cdf.shape[-1] - 1
    k = np.minimum(np.sum(cdf[..., 1:-1] <= u[..., None], axis=-1), n - 1)
    lo = np.take_along_axis(cdf, k[..., None], -1)[..., 0].astype(np.float64)
    hi = np.take_along_axis(cdf, k[..., None] + 1, -1)[..., 0].astype(np.float64)
    return k, np.clip((u - lo) / np.maximum(hi - lo, 1e-30), 0.0, 1.0)


def sample_binned(s: BinnedSampler, bins: np.ndarray, u1: np.ndarray, u2: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Directions (n, 3) and their densities (1/sr) for uniforms ``u1``, ``u2`` in [0, 1),
    the same procedure as the renderer's kernel: block row from ``u1``, block column from
    ``u2``, texel in the block from the rest of ``u1``, position in the texel from the rests."""
    h, w, cr, cc = s.shape
    bh, bw = s.block_shape
    bins = np.asarray(bins)
    i, fv0 = _invert(s.bin_marginal[bins], np.asarray(u1, np.float64))
    j, fu = _invert(s.bin_conditional[bins, i], np.asarray(u2, np.float64))
    k, fv = _invert(s.block_cdf[i * cc + j], fv0)
    row, col = i * bh + k // bw, j * bw + k % bw
    e = s.cos_theta_edges.astype(np.float64)
    cos_t = e[row] + fv * (e[row + 1] - e[row])
    sin_t = np.sqrt(np.maximum(0.0, 1.0 - cos_t ** 2))
    phi = 2.0 * np.pi * (col + fu) / w
    d = np.stack([sin_t * np.cos(phi), sin_t * np.sin(phi), cos_t], axis=-1)
    return d, _probabilities(s, bins, row, col) / texel_solid_angles(h, w)[row]
