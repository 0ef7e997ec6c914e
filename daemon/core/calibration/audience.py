"""Audience regions: people walking past, not one eye at one spot.

A region is a polygon on the ground (world metres, the frame of :mod:`grassd.sim.scene`: display
centre at the origin, +x east, +y north, the display surface is z = 0) plus a range of eye
heights above the display surface (cm). :meth:`AudienceRegion.sample` lays a regular grid over
the polygon (even-odd rule) and crosses it with evenly spaced eye heights;
:func:`simulate_region` computes the characteristic of one pixel (default: the display's centre
pixel, neighbours present) from every sampled eye, each from its own direction
(:func:`grassd.daemon.core.calibration.display_model.geometry_from_eye`).

The table (:func:`region_table`): for viewpoint j with monotone fitted characteristic f_j
(:func:`grassd.calib.fit_characteristic`), driving level v at length L gives the deviation from
linear OGCD ``e_j(v, L) = f_j(L) - (f_j(L_min) + v / 255 (f_j(L_max) - f_j(L_min)))`` [dE00]
(each viewer's own range, as the paper's 8-bit calibration defines it). The levels separate, so
for every level the length minimising ``sum_j w_j |e_j|`` (objective "mean") or ``max_j |e_j|``
(objective "worst") is found exactly on a grid of lengths (1 um by default), vectorised, then the
table is made non-decreasing.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from grassd.calib.characteristic import FittedCharacteristic
from grassd.calib.length_table import LEVELS
from grassd.daemon.core.calibration.display_model import (
    DisplaySimulationError,
    geometry_from_eye,
)
from grassd.daemon.core.calibration.simulation import SimulatedCurve, simulate_curve

OBJECTIVES = ("mean", "worst")


class AudienceError(DisplaySimulationError):
    """An audience region or a region table request is invalid (the message names the fix)."""


def points_in_polygon(points: np.ndarray, polygon: np.ndarray) -> np.ndarray:
    """Even-odd rule: which of ``points`` (P, 2) lie inside ``polygon`` (K, 2), vectorised.

    >>> sq = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], float)
    >>> points_in_polygon(np.array([[0.5, 0.5], [1.5, 0.5]]), sq).tolist()
    [True, False]
    """
    p = np.asarray(points, np.float64)[:, None, :]
    a = np.asarray(polygon, np.float64)
    b = np.roll(a, -1, axis=0)
    ay, by = a[None, :, 1], b[None, :, 1]
    crosses = (ay > p[..., 1]) != (by > p[..., 1])
    with np.errstate(divide="ignore", invalid="ignore"):
        x_at = a[None, :, 0] + (p[..., 1] - ay) * (b[None, :, 0] - a[None, :, 0]) / (by - ay)
    return (np.count_nonzero(crosses & (p[..., 0] < x_at), axis=1) % 2) == 1


@dataclass(frozen=True, eq=False)
class AudienceSamples:
    """Sampled eyes of a region.

    ``eyes_m`` (M, 3) world eye positions [m]; ``ground`` (M,) index of each eye's ground point
    in ``ground_xy`` (P, 2) [m]; ``heights_cm`` (H,) the eye heights; ``grid_x``/``grid_y`` the
    sampling grid's centres [m] and ``cell_of_ground`` (P, 2) each ground point's (iy, ix) cell,
    for heat maps.
    """

    eyes_m: np.ndarray
    ground: np.ndarray
    ground_xy: np.ndarray
    heights_cm: np.ndarray
    grid_x: np.ndarray
    grid_y: np.ndarray
    cell_of_ground: np.ndarray

    @property
    def n(self) -> int:
        """Number of sampled eyes M."""
        return len(self.eyes_m)


@dataclass(frozen=True, eq=False)
class AudienceRegion:
    """A ground polygon (K, 2) [m, world frame] and an eye-height range (lo, hi) [cm]."""

    polygon_m: np.ndarray
    h_cm: tuple[float, float]

    def __post_init__(self) -> None:
        poly = np.asarray(self.polygon_m, dtype=np.float64)
        if poly.ndim != 2 or poly.shape[1] != 2 or len(poly) < 3:
            raise AudienceError("an audience polygon needs at least 3 [x, y] vertices (m)")
        if not np.all(np.isfinite(poly)):
            raise AudienceError("audience polygon vertices must be finite numbers (m)")
        object.__setattr__(self, "polygon_m", poly)
        if self.area_m2 <= 1e-6:
            raise AudienceError("the audience polygon has no area; list its corners in order")
        lo, hi = (float(v) for v in self.h_cm)
        if not (math.isfinite(lo) and math.isfinite(hi) and 10 <= lo <= hi <= 1000):
            raise AudienceError(f"eye heights {self.h_cm} cm must satisfy 10 <= low <= high "
                                "<= 1000")
        object.__setattr__(self, "h_cm", (lo, hi))

    @property
    def area_m2(self) -> float:
        """Polygon area [m^2] (shoelace formula)."""
        x, y = self.polygon_m[:, 0], self.polygon_m[:, 1]
        return 0.5 * abs(float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))))

    def sample(self, n_ground: int = 16, n_heights: int = 2) -> AudienceSamples:
        """About ``n_ground`` ground points on a square grid over the polygon (cell centres
        inside it; at least one) crossed with ``n_heights`` evenly spaced eye heights (the
        middle one when 1). Deterministic."""
        if n_ground < 1 or n_heights < 1:
            raise AudienceError("sample at least one ground point and one eye height")
        lo_xy, hi_xy = self.polygon_m.min(axis=0), self.polygon_m.max(axis=0)
        step = math.sqrt(self.area_m2 / n_ground)
        nx = max(1, int(math.ceil((hi_xy[0] - lo_xy[0]) / step)))
        ny = max(1, int(math.ceil((hi_xy[1] - lo_xy[1]) / step)))
        gx = lo_xy[0] + (hi_xy[0] - lo_xy[0]) * (np.arange(nx) + 0.5) / nx
        gy = lo_xy[1] + (hi_xy[1] - lo_xy[1]) * (np.arange(ny) + 0.5) / ny
        iy, ix = np.meshgrid(np.arange(ny), np.arange(nx), indexing="ij")
        pts = np.stack([gx[ix.ravel()], gy[iy.ravel()]], axis=1)
        inside = points_in_polygon(pts, self.polygon_m)
        if not inside.any():  # a thin polygon between grid centres: take its vertex mean
            centre = self.polygon_m.mean(axis=0)
            d = np.linalg.norm(pts - centre, axis=1)
            inside = d == d.min()
        cells = np.stack([iy.ravel(), ix.ravel()], axis=1)[inside]
        ground_xy = pts[inside]
        lo, hi = self.h_cm
        heights = np.array([(lo + hi) / 2]) if n_heights == 1 else np.linspace(lo, hi, n_heights)
        g_idx, h_idx = np.meshgrid(np.arange(len(ground_xy)), np.arange(len(heights)),
                                   indexing="ij")
        eyes = np.column_stack([ground_xy[g_idx.ravel()], heights[h_idx.ravel()] / 100.0])
        return AudienceSamples(eyes_m=eyes, ground=g_idx.ravel(), ground_xy=ground_xy,
                               heights_cm=heights, grid_x=gx, grid_y=gy, cell_of_ground=cells)


def centre_pixel(display) -> int:
    """Index of the display's centre pixel (row-major)."""
    return (display.rows // 2) * display.cols + display.cols // 2


def simulate_region(renderer, display, lighting, samples: AudienceSamples,
                    lengths_mm: np.ndarray, settings, *, pixel_index: int | None = None,
                    target_stderr: float | None = None, ccm=None, spectral=None,
                    progress: Callable[[int, int], None] | None = None
                    ) -> list[SimulatedCurve]:
    """One :class:`SimulatedCurve` per sampled eye for pixel ``pixel_index`` (default the
    centre pixel) of ``display``, each seen from its own direction. Same seed for every eye
    (common random numbers across viewpoints). ``progress(done, total)`` per eye; ``spectral``:
    :func:`~grassd.daemon.core.calibration.simulation.simulate_curve`'s."""
    p = centre_pixel(display) if pixel_index is None else int(pixel_index)
    curves = []
    for k, eye in enumerate(samples.eyes_m):
        vp = geometry_from_eye(display, eye).viewpoint(p)
        curves.append(simulate_curve(renderer, display, lighting, vp, lengths_mm, settings,
                                     ccm=ccm, pixel_index=p, target_stderr=target_stderr,
                                     spectral=spectral))
        if progress:
            progress(k + 1, samples.n)
    return curves


def table_deviations(fits: Sequence[FittedCharacteristic], table_mm: np.ndarray) -> np.ndarray:
    """(J, 256) deviation from linear OGCD [dE00] of every viewpoint when levels 0..255 drive
    the lengths ``table_mm`` (256,) [mm] (see the module docstring for e_j)."""
    table_mm = np.asarray(table_mm, np.float64)
    v = np.arange(LEVELS) / (LEVELS - 1)
    out = np.empty((len(fits), LEVELS))
    for j, f in enumerate(fits):  # one fitted spline per viewpoint
        out[j] = f(table_mm) - (f.ogcd_min + v * f.ogcd_range)
    return out


@dataclass(frozen=True, eq=False)
class RegionTable:
    """The region's table and what every viewpoint gets from it.

    ``lengths_um`` (256,) uint16 [um]; ``objective`` "mean" | "worst"; ``deviation`` (J, 256)
    [dE00]; ``max_error``/``mean_error`` (J,) largest / mean |deviation| over levels [dE00];
    ``ogcd_range`` (J,) each viewpoint's fitted OGCD range [dE00]; ``weights`` (J,).
    """

    lengths_um: np.ndarray
    objective: str
    deviation: np.ndarray
    max_error: np.ndarray
    mean_error: np.ndarray
    ogcd_range: np.ndarray
    weights: np.ndarray
    seconds: dict[str, float] = field(default_factory=dict)

    @property
    def lengths_mm(self) -> np.ndarray:
        """The table in millimetres."""
        return self.lengths_um.astype(np.float64) / 1000.0

    def summary(self) -> dict[str, float | str | int]:
        """Region-wide numbers for reports (dE00)."""
        w = self.weights / self.weights.sum()
        return {"objective": self.objective, "viewpoints": int(len(self.max_error)),
                "worst_error": float(self.max_error.max()),
                "mean_error": float(w @ self.mean_error),
                "min_ogcd_range": float(self.ogcd_range.min()),
                "max_ogcd_range": float(self.ogcd_range.max())}


def evaluate_table(fits: Sequence[FittedCharacteristic], lengths_um: np.ndarray,
                   objective: str = "mean", weights: np.ndarray | None = None) -> RegionTable:
    """What table ``lengths_um`` (256,) [um] gives every viewpoint of ``fits``."""
    w = np.ones(len(fits)) if weights is None else np.asarray(weights, np.float64)
    dev = table_deviations(fits, np.asarray(lengths_um, np.float64) / 1000.0)
    return RegionTable(lengths_um=np.asarray(lengths_um, np.uint16), objective=objective,
                       deviation=dev, max_error=np.abs(dev).max(axis=1),
                       mean_error=np.abs(dev).mean(axis=1),
                       ogcd_range=np.array([f.ogcd_range for f in fits]), weights=w)


def region_table(fits: Sequence[FittedCharacteristic], objective: str = "mean",
                 weights: np.ndarray | None = None, step_um: int = 1,
                 chunk_levels: int = 16) -> RegionTable:
    """The table minimising the weighted mean (or the worst) |deviation from linear OGCD| over
    the viewpoints, level by level, exactly on a ``step_um`` grid of lengths [um].

    All fits must share the length range (same simulated lengths). Level 0 is the shortest
    length; the table is made non-decreasing (``np.maximum.accumulate``).
    """
    if objective not in OBJECTIVES:
        raise AudienceError(f"objective must be one of {OBJECTIVES}, got {objective!r}")
    if not fits:
        raise AudienceError("no viewpoints to build a region table from")
    lo = {round(f.min_length_mm, 9) for f in fits}
    hi = {round(f.max_length_mm, 9) for f in fits}
    if len(lo) != 1 or len(hi) != 1:
        raise AudienceError("all viewpoints must be simulated over the same lengths")
    t0 = time.perf_counter()
    w = np.ones(len(fits)) if weights is None else np.asarray(weights, np.float64)
    if w.shape != (len(fits),) or np.any(w < 0) or w.sum() <= 0:
        raise AudienceError("weights must be one non-negative number per viewpoint, not all 0")
    lo_um = int(round(fits[0].min_length_mm * 1000))
    hi_um = int(round(fits[0].max_length_mm * 1000))
    grid_um = np.arange(lo_um, hi_um + 1, max(1, int(step_um)))
    if grid_um[-1] != hi_um:
        grid_um = np.append(grid_um, hi_um)
    f_grid = np.stack([f(grid_um / 1000.0) for f in fits])  # (J, G)
    lows = np.array([f.ogcd_min for f in fits])
    ranges = np.array([f.ogcd_range for f in fits])
    levels = np.arange(LEVELS) / (LEVELS - 1)
    best = np.empty(LEVELS, np.int64)
    wn = w / w.sum()
    for s in range(0, LEVELS, chunk_levels):  # bounded memory: chunk x J x G
        target = lows[None, :] + levels[s:s + chunk_levels, None] * ranges[None, :]  # (C, J)
        err = np.abs(f_grid[None, :, :] - target[:, :, None])  # (C, J, G)
        cost = np.einsum("j,cjg->cg", wn, err) if objective == "mean" else err.max(axis=1)
        best[s:s + chunk_levels] = cost.argmin(axis=1)
    table = np.maximum.accumulate(grid_um[best])
    table[0] = lo_um
    out = evaluate_table(fits, table, objective, w)
    return RegionTable(**{**out.__dict__, "seconds": {"optimise": time.perf_counter() - t0}})


def region_from_config(audience) -> tuple[AudienceRegion, AudienceSamples]:
    """The region and its samples from a config ``[audience]`` table
    (:class:`grassd.daemon.core.config.settings.AudienceConfig`)."""
    region = AudienceRegion(np.asarray(audience.polygon, np.float64), tuple(audience.h_cm))
    return region, region.sample(audience.ground_samples, audience.height_samples)
