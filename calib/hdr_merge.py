"""Merge an exposure bracket into one scene-linear radiance map.

Two kinds of bracket:

* **8-bit encoded shots** (JPEG): the camera's response (code -> relative exposure) is not
  published for any real camera, so it is recovered from the bracket itself by Debevec & Malik
  (1997), "Recovering High Dynamic Range Radiance Maps from Photographs", SIGGRAPH: the
  least-squares solve of ``g(Z_ij) = ln E_i + ln dt_j`` with a second-derivative smoothness term
  (``colour_hdri.g_solve``), on samples chosen by histogram matching (Grossberg & Nayar 2003,
  ``colour_hdri.samples_Grossberg2003``), which needs no pixel alignment between shots.
  :func:`recover_response` returns the inverse response ``R[z, c]`` = relative exposure that
  gives code ``z`` in channel ``c``, anchored at ``R[128, c] = 1`` in every channel (the
  solve's own gauge ``g(128) = 0``), so a neutral grey keeps equal channels when the channels
  share one curve, as a white-balanced JPEG pipeline makes them.
* **Linear shots** (developed RAW / DNG): the response is the identity up to saturation.

The merge (:func:`merge_ldr`, :func:`merge_linear`) is the weighted mean of the per-shot
radiance estimates ``R(z) / H`` (``H`` = the shot's exposure, :func:`relative_exposure`), as in
Debevec & Malik (1997) eq. 6. The weight of a texel in a shot is the hat function of its code
(zero at the black and clip limits), taken over the texel's worst channel, so a texel with one
clipped channel is not used from that shot at all (no colour shift). Two exceptions make every
texel defined: a texel bright in the **shortest** exposure is taken from it (the highlights,
even where still clipped there: such a texel is flagged in :attr:`MergeResult.clipped`), and a
texel dark in the **longest** exposure is taken from that one (the shadows).

The result is relative radiance: one global scale is unknown (the camera's gain), which is
what the daemon's lux reading fixes. Units: ``exposures`` are relative exposures (s x ISO/100 /
N^2; only their ratios matter), radiance is linear in the input's RGB space.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from grassd.calib.errors import BracketBlackError, BracketClippedError, HdrMergeError

#: Number of codes of an 8-bit shot.
CODES: int = 256
#: Codes at or below this are treated as black (no information), at or above CLIP_CODE as
#: clipped: JPEG ringing moves codes by a few steps around the limits.
BLACK_CODE: int = 4
CLIP_CODE: int = 251
#: Linear shots: values at or above this fraction of full scale count as clipped; at or below
#: BLACK_LINEAR as black.
CLIP_LINEAR: float = 0.98
BLACK_LINEAR: float = 1e-3
#: A bracket whose shortest shot is clipped (or whose longest is black) over more than this
#: fraction of the texels cannot make a radiance map.
UNUSABLE_FRACTION: float = 0.5
#: Rows merged at a time: bounds the working memory (9 shots 6720 texels wide, as a THETA Z1
#: makes, need about 100 MB per 64 rows) without changing the result.
BLOCK_ROWS: int = 64
#: Samples per channel and smoothness lambda for the Debevec solve (N (P - 1) > 255 samples
#: are enough, Debevec & Malik 1997 section 2.1; lambda: with 2-EV steps the data only link codes
#: whose exposures differ by 4x, so the smoothness term must carry the curve in between).
RESPONSE_SAMPLES: int = 256
RESPONSE_SMOOTHING: float = 100.0


@dataclass(frozen=True, eq=False)
class MergeResult:
    """A merged bracket.

    Attributes:
        radiance: (H, W, 3) float32 relative linear radiance (input RGB space).
        clipped: (H, W) bool, texels clipped even in the shortest exposure (their radiance is
            a lower bound).
        black: (H, W) bool, texels black even in the longest exposure.
        method: how the shots were linearised ("debevec1997" or "linear").
        shots_used: number of shots that contributed to at least one texel.
    """

    radiance: NDArray[np.float32]
    clipped: NDArray[np.bool_]
    black: NDArray[np.bool_]
    method: str
    shots_used: int

    @property
    def clipped_fraction(self) -> float:
        """Share of texels clipped in the shortest exposure (0..1)."""
        return float(self.clipped.mean())

    @property
    def black_fraction(self) -> float:
        """Share of texels black in the longest exposure (0..1)."""
        return float(self.black.mean())


def relative_exposure(exposure_time_s: float, iso: float = 100.0,
                      f_number: float = 1.0) -> float:
    """Relative photometric exposure of a shot: ``t * (ISO / 100) / N^2`` (t in s).

    Only ratios between the shots of one bracket matter (the merge's scale is relative)."""
    if not (np.isfinite(exposure_time_s) and exposure_time_s > 0):
        raise HdrMergeError(f"exposure time must be > 0 s, got {exposure_time_s!r}")
    if not (np.isfinite(iso) and iso > 0 and np.isfinite(f_number) and f_number > 0):
        raise HdrMergeError(f"ISO and f-number must be > 0, got {iso!r}, {f_number!r}")
    return float(exposure_time_s) * float(iso) / 100.0 / float(f_number) ** 2


def _check_stack(images: Sequence[ArrayLike], exposures: ArrayLike, dtype: type
                 ) -> tuple[list[NDArray], NDArray[np.float64]]:
    imgs = [np.asarray(im) for im in images]
    h = np.asarray(exposures, dtype=np.float64).ravel()
    if len(imgs) < 2:
        raise HdrMergeError(f"a bracket needs at least 2 shots, got {len(imgs)}")
    if len(h) != len(imgs):
        raise HdrMergeError(f"{len(imgs)} shots but {len(h)} exposures")
    if not (np.isfinite(h).all() and (h > 0).all()):
        raise HdrMergeError(f"exposures must be finite and > 0, got {h.tolist()}")
    shape = imgs[0].shape
    for i, im in enumerate(imgs):
        if im.ndim != 3 or im.shape[2] != 3 or im.shape != shape:
            raise HdrMergeError(f"shot {i} has shape {im.shape}; every shot must be the same "
                                f"(H, W, 3) as shot 0 {shape}")
        if dtype is np.uint8 and im.dtype != np.uint8:
            raise HdrMergeError(f"shot {i} is {im.dtype}, not 8-bit codes (uint8)")
    if len(np.unique(h)) != len(h):
        raise HdrMergeError(f"two shots share one exposure ({h.tolist()}); a bracket needs "
                            "distinct exposures")
    order = np.argsort(h)
    return [imgs[i] for i in order], h[order]


def _hat(codes: NDArray[np.float64], lo: float, hi: float) -> NDArray[np.float64]:
    """Debevec's hat weight: 0 at and beyond ``lo``/``hi``, 1 in the middle."""
    mid = 0.5 * (lo + hi)
    w = np.where(codes <= mid, codes - lo, hi - codes) / (mid - lo)
    return np.clip(w, 0.0, 1.0)


def recover_response(images: Sequence[ArrayLike], exposures: ArrayLike, *,
                     samples: int = RESPONSE_SAMPLES,
                     smoothing: float = RESPONSE_SMOOTHING) -> NDArray[np.float64]:
    """Inverse camera response (256, 3) from an 8-bit bracket (Debevec & Malik 1997).

    ``images``: (H, W, 3) uint8 shots; ``exposures``: their relative exposures (any common
    unit). Returns ``R[z, c]`` = relative exposure producing code ``z`` in channel ``c``,
    strictly increasing, ``R[128, c] = 1``. Raises :class:`HdrMergeError` when the bracket
    holds too few mid-tone codes to constrain the curve.
    """
    from colour_hdri import g_solve, samples_Grossberg2003  # heavy: only when recovering
    from threadpoolctl import threadpool_limits

    imgs, h = _check_stack(images, exposures, np.uint8)
    _check_usable(imgs[0].max(axis=2) >= CLIP_CODE, imgs[-1].min(axis=2) <= BLACK_CODE)
    stack = np.stack([im.astype(np.float64) / (CODES - 1) for im in imgs], axis=-1)
    z = samples_Grossberg2003(stack, samples, CODES).astype(np.int64)  # (samples, N, 3)
    w_codes = _hat(np.arange(CODES, dtype=np.float64), BLACK_CODE, CLIP_CODE)
    useful = (w_codes[z] > 0).sum(axis=1) >= 2  # a sample seen well in two shots
    if useful.mean(axis=0).min() < 0.05:
        raise HdrMergeError("the bracket holds too few mid-tone codes seen in two shots to "
                            "recover the camera response: widen the bracket or use a scene "
                            "with more contrast, or a cached response")
    log_h = np.log(h)

    def weight(x: NDArray) -> NDArray:
        return _hat(np.asarray(x) * (CODES - 1), BLACK_CODE, CLIP_CODE)

    curves = []
    with threadpool_limits(1):  # a small dense solve: BLAS threads only fight over the cores
        for c in range(3):
            g, _ = g_solve(z[..., c], log_h, smoothing, weight, CODES)
            curves.append(g - g[CODES // 2])
    resp = np.exp(np.stack(curves, axis=-1))
    return _monotone(resp)


def _monotone(resp: NDArray[np.float64]) -> NDArray[np.float64]:
    """Make an inverse response strictly increasing (the codes outside the hat's support are
    not constrained by data: extend them by the slope in log of their neighbours)."""
    out = np.array(resp, dtype=np.float64)
    lo, hi = BLACK_CODE + 1, CLIP_CODE - 1
    logr = np.log(out)
    for c in range(3):
        s_lo = logr[lo + 1, c] - logr[lo, c]
        s_hi = logr[hi, c] - logr[hi - 1, c]
        logr[:lo, c] = logr[lo, c] - s_lo * np.arange(lo, 0, -1)
        logr[hi + 1:, c] = logr[hi, c] + s_hi * np.arange(1, CODES - hi)
    out = np.exp(logr)
    out = np.maximum.accumulate(out, axis=0)
    out += np.arange(CODES)[:, None] * 1e-9 * out[CODES // 2]  # strictly increasing
    return out / out[CODES // 2]


def _certainty(resp: NDArray[np.float64]) -> NDArray[np.float64]:
    """(256, 3) weight of a code by how precisely it gives the radiance: the inverse square of
    the relative radiance step of one code, ``(d ln R / dz)^-2`` (quantisation noise in linear
    units, as in Robertson et al. 2003 and Mitsunaga & Nayar 1999), normalised to max 1."""
    slope = np.gradient(np.log(resp), axis=0)
    c = 1.0 / np.maximum(slope, 1e-6) ** 2
    return c / c.max(axis=0)


def merge_ldr(images: Sequence[ArrayLike], exposures: ArrayLike, response: ArrayLike,
              block_rows: int | None = None) -> MergeResult:
    """Merge 8-bit shots (H, W, 3 uint8) of relative ``exposures`` with the inverse response
    ``response`` (256, 3) (from :func:`recover_response` or a cache) into relative linear
    radiance (module docstring), ``block_rows`` rows at a time (default :data:`BLOCK_ROWS`).
    Raises :class:`BracketClippedError` / :class:`BracketBlackError` when even the shortest /
    longest shot is clipped / black over more than :data:`UNUSABLE_FRACTION` of the texels."""
    imgs, h = _check_stack(images, exposures, np.uint8)
    resp = np.asarray(response, dtype=np.float64)
    if resp.shape != (CODES, 3) or not np.isfinite(resp).all() or (resp <= 0).any():
        raise HdrMergeError(f"response must be (256, 3), finite and > 0; got shape "
                            f"{resp.shape}, smallest {np.nanmin(resp) if resp.size else None}")
    if (np.diff(resp, axis=0) <= 0).any():
        raise HdrMergeError("response must increase with the code in every channel")
    clipped = imgs[0].max(axis=2) >= CLIP_CODE
    black = imgs[-1].min(axis=2) <= BLACK_CODE
    _check_usable(clipped, black)
    channels = np.arange(3)
    certainty = _certainty(resp)

    def block(rows: slice) -> tuple[list[NDArray], list[NDArray], NDArray, NDArray]:
        part = [im[rows] for im in imgs]
        lin = [resp[p, channels] / hk for p, hk in zip(part, h, strict=True)]
        weights = [np.minimum(_hat(p.min(axis=2).astype(np.float64), BLACK_CODE, CLIP_CODE),
                              _hat(p.max(axis=2).astype(np.float64), BLACK_CODE, CLIP_CODE))
                   * certainty[p, channels].min(axis=2) for p in part]
        return lin, weights, part[0].max(axis=2) >= CODES // 2, part[-1].min(axis=2) < CODES // 2

    return _merge_blocks(block, clipped, black, "debevec1997", len(imgs), block_rows)


def merge_linear(images: Sequence[ArrayLike], exposures: ArrayLike,
                 block_rows: int | None = None) -> MergeResult:
    """Merge linear shots (H, W, 3 float, 1 = full scale, e.g. developed DNGs) of relative
    ``exposures``: the weight of a texel is its exposure (photon noise) while it is neither
    clipped (>= :data:`CLIP_LINEAR`) nor black (<= :data:`BLACK_LINEAR`); highlights and
    shadows as in :func:`merge_ldr`."""
    imgs, h = _check_stack(images, exposures, np.floating)
    for k, im in enumerate(imgs):
        if not np.isfinite(im).all():
            raise HdrMergeError(f"shot {k} holds NaN or infinite values")
    clipped = imgs[0].max(axis=2) >= CLIP_LINEAR
    black = imgs[-1].min(axis=2) <= BLACK_LINEAR
    _check_usable(clipped, black)

    def block(rows: slice) -> tuple[list[NDArray], list[NDArray], NDArray, NDArray]:
        part = [np.asarray(im[rows], dtype=np.float64) for im in imgs]
        lin = [np.maximum(x, 0.0) / hk for x, hk in zip(part, h, strict=True)]
        weights = [((x.max(axis=2) < CLIP_LINEAR) & (x.min(axis=2) > BLACK_LINEAR)) * (hk / h[-1])
                   for x, hk in zip(part, h, strict=True)]
        return lin, weights, part[0].max(axis=2) >= 0.5, part[-1].min(axis=2) < 0.5

    return _merge_blocks(block, clipped, black, "linear", len(imgs), block_rows)


def _check_usable(clipped: NDArray, black: NDArray) -> None:
    """Refuse a bracket clipped in its shortest or black in its longest shot over more than
    :data:`UNUSABLE_FRACTION` of the texels."""
    if clipped.mean() > UNUSABLE_FRACTION:
        raise BracketClippedError(
            f"{100 * clipped.mean():.0f}% of the image is clipped even in the shortest "
            "exposure: shorten the bracket's exposures (lower ISO, faster shutter)")
    if black.mean() > UNUSABLE_FRACTION:
        raise BracketBlackError(
            f"{100 * black.mean():.0f}% of the image is black even in the longest exposure: "
            "lengthen the bracket's exposures (or check the lens cap)")


def _merge_blocks(block, clipped: NDArray, black: NDArray, method: str, shots: int,
                  block_rows: int | None) -> MergeResult:
    """Run :func:`_combine` on row blocks (``block(rows)`` gives their linear estimates,
    weights and highlight/shadow masks) into one map."""
    rows_per = block_rows or BLOCK_ROWS
    height, width = clipped.shape
    out = np.empty((height, width, 3), dtype=np.float32)
    used = np.zeros(shots, dtype=bool)
    for r0 in range(0, height, rows_per):
        rows = slice(r0, r0 + rows_per)
        lin, weights, bright, dark = block(rows)
        out[rows], part_used = _combine(lin, weights, bright, dark, clipped[rows])
        used |= part_used
    return MergeResult(radiance=out, clipped=clipped, black=black, method=method,
                       shots_used=int(used.sum()))


def _combine(lin: list[NDArray], weights: list[NDArray], bright_in_shortest: NDArray,
             dark_in_longest: NDArray, clipped: NDArray) -> tuple[NDArray, NDArray]:
    """Weighted mean of the shots' radiance estimates (module docstring): (radiance, which
    shots contributed)."""
    w = [np.array(x, dtype=np.float64) for x in weights]
    w[0] = np.where(bright_in_shortest & (w[0] == 0), 1.0, w[0])
    w[0] = np.where(clipped, 1.0, w[0])  # nothing better than the shortest exists there
    for k in range(1, len(w)):
        w[k] = np.where(clipped, 0.0, w[k])
    w[-1] = np.where(dark_in_longest & (w[-1] == 0) & ~clipped, 1e-3, w[-1])
    num = np.zeros(lin[0].shape, dtype=np.float64)
    den = np.zeros(lin[0].shape[:2], dtype=np.float64)
    for x, wk in zip(lin, w, strict=True):
        num += x * wk[..., None]
        den += wk
    used = np.array([(wk > 0).any() for wk in w])
    return (num / np.maximum(den, 1e-12)[..., None]).astype(np.float32), used
