"""Whole displays: every pixel of a ``DisplaySpec`` seen by one viewer, neighbours present.

A real installation is ``rows x cols`` grass pixels. Two things differ from a lone pixel:

* Neighbours: at oblique views a pixel's tall green grass shades and hides its neighbour's yellow
  grass. :meth:`grassd.sim.renderer.Renderer.characteristic` always traces the whole display, so
  every measurement here has its neighbours (and a border pixel lacks some, as on site).
* Direction: a viewer standing at one spot sees each pixel from a different direction. Viewpoints
  in ``grassd.sim`` are relative to the measured pixel's centre, so for a viewer at world point
  ``E`` (metres; display centre at the origin, z up, see :mod:`grassd.sim.scene`) pixel ``i`` at
  centre ``c_i`` gets its own viewpoint::

      h_i = 100 E_z [cm],  d_i = |E_xy - c_i| [m],  theta_i = atan2(E_x - c_ix, -(E_y - c_iy))

  which is the inverse of :meth:`Viewpoint.eye_m` (``eye = c + (d sin theta, -d cos theta, h)``).
  A configured viewpoint ``(h, d, theta)`` of a display is taken relative to the display centre
  (``eye="world"``, the default); ``eye="pixel"`` keeps the old per-pixel reading in which every
  pixel is seen from the same relative direction.

Cost grows with the number of distinct viewing geometries, not of pixels: :func:`group_pixels`
bins the view directions (elevation and azimuth, tolerance in degrees), the viewing distance
(relative tolerance) and, by default, which of the four neighbours exist; one representative per
group is traced and its characteristic stands for every member. :class:`GroupingError` measures
what that costs by also tracing the member farthest from its representative, and
:func:`errors_on` over every pixel against a per-pixel run. Grouping is only sound when pixels
differ by geometry alone, so per-pixel tables trace one tuft layout shared by every pixel
(:func:`shares_layout`). What a tolerance costs is measured in docs/calibration.md.

Tables (:func:`build_display_tables`): one per pixel (per group, shared by its members), one per
controller (its pixels' mean characteristic) or one global table (all pixels' mean). Every
pixel's error is the largest deviation of its OGCD from the linear ramp of its own OGCD range
when driven by its table (CIEDE2000 units). ``grassd run`` pushes these tables to the
controllers (:mod:`grassd.daemon.core.calibration.units`).
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from grassd.calib.characteristic import (
    Characteristic,
    FittedCharacteristic,
    fit_characteristic,
    floor_stderr,
)
from grassd.calib.length_table import LEVELS, LengthTable, build_length_table
from grassd.daemon.core.calibration.run_report import GroupingSummary
from grassd.daemon.core.calibration.simulation import SimulatedCurve, simulate_curve
from grassd.daemon.core.errors import DaemonError

#: Closest a viewer may stand to a pixel centre horizontally (m): straight above is undefined.
MIN_DISTANCE_M: float = 1e-3
EYE_MODES = ("world", "pixel")
GRANULARITIES = ("pixel", "controller", "global")
LAYOUTS = ("auto", "shared", "per_pixel")


class DisplaySimulationError(DaemonError):
    """A whole-display simulation or table request is inconsistent (fix the named argument)."""


# --------------------------------------------------------------------------- geometry


@dataclass(frozen=True, eq=False)
class PixelGeometry:
    """How one viewer sees every pixel: arrays of shape (N,), N = rows x cols (row-major).

    ``centres_m`` (N, 2) pixel centres [m]; ``h_cm`` eye height [cm], ``d_m`` horizontal
    distance [m], ``theta_deg`` horizontal angle [deg] of the eye relative to each pixel centre
    (the paper's viewpoint convention); ``elevation_deg`` = atan(h / d) [deg]; ``neighbours``
    4-bit mask of the neighbours present (1: row - 1, 2: row + 1, 4: col - 1, 8: col + 1).
    """

    centres_m: np.ndarray
    h_cm: np.ndarray
    d_m: np.ndarray
    theta_deg: np.ndarray
    neighbours: np.ndarray

    @property
    def n_pixels(self) -> int:
        """Number of pixels N."""
        return len(self.h_cm)

    @property
    def elevation_deg(self) -> np.ndarray:
        """Elevation of the eye seen from each pixel centre [deg]."""
        return np.degrees(np.arctan2(self.h_cm / 100.0, self.d_m))

    @property
    def directions(self) -> np.ndarray:
        """(N, 3) unit vectors from each pixel centre towards the eye (world frame)."""
        e = np.radians(self.elevation_deg)
        t = np.radians(self.theta_deg)
        return np.stack([np.sin(t) * np.cos(e), -np.cos(t) * np.cos(e), np.sin(e)], axis=1)

    def viewpoint(self, i: int):
        """The ``grassd.sim.scene.Viewpoint`` of pixel ``i``."""
        from grassd.sim.scene import Viewpoint

        return Viewpoint(float(self.h_cm[i]), float(self.d_m[i]), float(self.theta_deg[i]))


def neighbour_mask(rows: int, cols: int) -> np.ndarray:
    """(rows*cols,) 4-bit masks of the neighbours each pixel has (see :class:`PixelGeometry`).

    >>> neighbour_mask(1, 3).tolist()
    [8, 12, 4]
    """
    r, c = np.meshgrid(np.arange(rows), np.arange(cols), indexing="ij")
    mask = ((r > 0) * 1 + (r < rows - 1) * 2 + (c > 0) * 4 + (c < cols - 1) * 8)
    return mask.ravel().astype(np.int64)


def geometry_from_eye(display, eye_m: np.ndarray) -> PixelGeometry:
    """Per-pixel viewpoints of a viewer whose eye is at world point ``eye_m`` (3,) [m].

    The display lies in the plane z = 0 centred on the origin; ``eye_m[2]`` is the eye height
    above it [m]. A pixel whose centre lies closer than :data:`MIN_DISTANCE_M` horizontally is
    treated as seen from that distance (the view straight down has no defined theta).

    >>> from grassd.sim.scene import DisplaySpec
    >>> g = geometry_from_eye(DisplaySpec(rows=1, cols=3), np.array([0.0, -2.0, 1.7]))
    >>> g.theta_deg.round(3).tolist(), g.d_m.round(4).tolist()
    ([0.96, 0.0, -0.96], [2.0003, 2.0, 2.0003])
    """
    eye = np.asarray(eye_m, dtype=np.float64).reshape(3)
    if not np.all(np.isfinite(eye)) or eye[2] <= 0:
        raise DisplaySimulationError(f"eye position {eye.tolist()} m must be finite and above "
                                     "the display plane (z > 0)")
    centres = display.pixel_centres_m()
    rel = eye[:2] - centres
    d = np.maximum(np.hypot(rel[:, 0], rel[:, 1]), MIN_DISTANCE_M)
    theta = np.degrees(np.arctan2(rel[:, 0], -rel[:, 1]))
    h = np.full(len(centres), eye[2] * 100.0)
    return PixelGeometry(centres_m=centres, h_cm=h, d_m=d, theta_deg=theta,
                         neighbours=neighbour_mask(display.rows, display.cols))


def pixel_geometry(display, viewer, eye: str = "world") -> PixelGeometry:
    """Per-pixel viewpoints for a viewer given as a ``Viewpoint`` (h cm, d m, theta deg).

    ``eye="world"``: the viewer stands at one spot, ``viewer`` relative to the display centre;
    ``eye="pixel"``: every pixel is seen from ``viewer`` relative to its own centre.
    """
    if eye not in EYE_MODES:
        raise DisplaySimulationError(f"eye must be one of {EYE_MODES}, got {eye!r}")
    if eye == "world":
        return geometry_from_eye(display, viewer.eye_m((0.0, 0.0)))
    n = display.rows * display.cols
    return PixelGeometry(centres_m=display.pixel_centres_m(), h_cm=np.full(n, viewer.h_cm),
                         d_m=np.full(n, viewer.d_m), theta_deg=np.full(n, viewer.theta_deg),
                         neighbours=neighbour_mask(display.rows, display.cols))


def shares_layout(granularity: str, layout: str = "auto") -> bool:
    """Whether a display simulated for ``granularity`` tables traces one tuft layout copied to
    every pixel (``layout`` "shared"), each pixel's own random layout ("per_pixel"), or, for
    "auto", shared exactly when the tables are per pixel.

    Why: the simulated layout is a random draw, not the installed pixel's real tufts (those
    are not measured). Pixels of the same display with their own random layouts differ by up
    to 1.9 dE00 (OGCD, courtyard + sun, 8 x 8 at 2 m) even when seen from within 1 deg of each
    other, so per-pixel tables would be fitted to layout noise, and grouping by viewing
    geometry (which per-pixel tables need to stay affordable) would be wrong by as much. With
    one shared layout two pixels seen from the same direction differ by 0.03 dE00: what
    remains between pixels is what the tables should correct (view direction, distance,
    neighbours). Controller and global tables average many pixels, so there independent
    layouts average the draw out.

    >>> shares_layout("pixel"), shares_layout("controller"), shares_layout("global", "shared")
    (True, False, True)
    """
    if layout not in LAYOUTS:
        raise DisplaySimulationError(f"layout {layout!r} must be one of {LAYOUTS}")
    return layout == "shared" or (layout == "auto" and granularity == "pixel")


def display_spec_for_config(cfg):
    """The ``DisplaySpec`` of a daemon ``Config``: ``[display]`` (pixel, rows, cols, pitch in
    mm) with the tuft layout of ``[tables]`` (:func:`shares_layout`)."""
    from grassd.sim.scene import DisplaySpec, PixelSpec

    d = cfg.display
    return DisplaySpec(PixelSpec(**dict(d.pixel)), d.rows, d.cols, d.pitch_mm,
                       same_layout=shares_layout(cfg.tables.granularity, cfg.tables.layout))


def capacity_for(n_pixels: int):
    """A ``grassd.sim.renderer.Capacity`` large enough for a display of ``n_pixels`` default
    pixels (the default Capacity holds 8 x 8; about 300 blades, 30 rectangles and 2300 grid
    items per pixel, with headroom), rounded up to powers of two."""
    from grassd.sim.renderer import Capacity

    if n_pixels <= 64:
        return Capacity()
    p2 = lambda x: 1 << int(math.ceil(math.log2(max(x, 1))))  # noqa: E731
    return Capacity(blades=p2(340 * n_pixels), rects=p2(32 * n_pixels),
                    items=p2(2600 * n_pixels), cells=p2(400 * n_pixels + 4096))


# --------------------------------------------------------------------------- grouping


@dataclass(frozen=True, eq=False)
class PixelGroups:
    """Pixels binned by viewing geometry.

    ``labels`` (N,) group of every pixel; ``representatives`` (G,) the pixel traced for each
    group (the member nearest the group's mean view direction); ``spread_deg`` (G,) largest
    angle [deg] between a member's view direction and its representative's; ``farthest`` (G,)
    the member at that angle; ``tolerance_deg`` the bin size used (0 = no grouping).
    """

    labels: np.ndarray
    representatives: np.ndarray
    spread_deg: np.ndarray
    farthest: np.ndarray
    tolerance_deg: float

    @property
    def n_groups(self) -> int:
        """Number of groups G (= traced characteristics)."""
        return len(self.representatives)

    @property
    def sizes(self) -> np.ndarray:
        """(G,) number of pixels in each group."""
        return np.bincount(self.labels, minlength=self.n_groups)

    def members(self, g: int) -> np.ndarray:
        """Pixel indices of group ``g``."""
        return np.flatnonzero(self.labels == g)


def _first_per_label(labels: np.ndarray, key: np.ndarray, n: int) -> np.ndarray:
    """Index of the element with the smallest ``key`` within each label 0..n-1."""
    order = np.lexsort((key, labels))
    first = np.concatenate(([True], np.diff(labels[order]) != 0))
    out = np.empty(n, dtype=np.int64)
    out[labels[order][first]] = order[first]
    return out


def group_pixels(geometry: PixelGeometry, tolerance_deg: float = 2.0,
                 distance_tolerance: float = 0.1, by_neighbours: bool = True) -> PixelGroups:
    """Group pixels whose viewing geometry differs by less than a tolerance.

    Bins: elevation in steps of ``tolerance_deg``; azimuth in steps of
    ``tolerance_deg / cos(elevation)`` (equal angles on the sphere); distance in steps of
    ``log(1 + distance_tolerance)`` (relative); and, with ``by_neighbours``, the neighbour mask,
    so a border pixel is never represented by an interior one. Within a group the elevations
    differ by less than ``tolerance_deg``. ``tolerance_deg = 0`` puts every pixel in its own
    group (per-pixel simulation). Vectorised; O(N log N).

    >>> from grassd.sim.scene import DisplaySpec, Viewpoint
    >>> g = pixel_geometry(DisplaySpec(rows=4, cols=4), Viewpoint(170, 2, 0))
    >>> group_pixels(g, 30.0, by_neighbours=False).n_groups
    1
    >>> group_pixels(g, 0.0).n_groups
    16
    """
    if not (math.isfinite(tolerance_deg) and tolerance_deg >= 0):
        raise DisplaySimulationError(f"grouping tolerance {tolerance_deg!r} deg must be >= 0")
    if not (math.isfinite(distance_tolerance) and distance_tolerance > 0):
        raise DisplaySimulationError(f"distance tolerance {distance_tolerance!r} must be > 0")
    n = geometry.n_pixels
    dirs = geometry.directions
    if tolerance_deg == 0:
        labels = np.arange(n)
    else:
        elev = geometry.elevation_deg
        e_bin = np.floor(elev / tolerance_deg)
        band_cos = np.maximum(np.cos(np.radians((e_bin + 0.5) * tolerance_deg)), 0.05)
        a_bin = np.floor((geometry.theta_deg + 180.0) / (tolerance_deg / band_cos))
        d_bin = np.floor(np.log(geometry.d_m) / math.log1p(distance_tolerance))
        nb = geometry.neighbours if by_neighbours else np.zeros(n)
        keys = np.stack([e_bin, a_bin, d_bin, nb], axis=1)
        _, labels = np.unique(keys, axis=0, return_inverse=True)
        labels = labels.reshape(-1)
    g = int(labels.max()) + 1
    mean = np.zeros((g, 3))
    np.add.at(mean, labels, dirs)
    mean /= np.linalg.norm(mean, axis=1, keepdims=True)
    to_mean = np.einsum("ij,ij->i", dirs, mean[labels])
    reps = _first_per_label(labels, -to_mean, g)
    cos_rep = np.clip(np.einsum("ij,ij->i", dirs, dirs[reps[labels]]), -1.0, 1.0)
    far = _first_per_label(labels, cos_rep, g)
    spread = np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", dirs[far], dirs[reps]),
                                          -1.0, 1.0)))
    return PixelGroups(labels=labels, representatives=reps, spread_deg=spread, farthest=far,
                       tolerance_deg=float(tolerance_deg))


# --------------------------------------------------------------------------- simulation


def table_deviation(fit: FittedCharacteristic, lengths_mm: np.ndarray) -> np.ndarray:
    """Deviation (dE00) of OGCD from the linear ramp of ``fit``'s own range when the levels
    0..255 are driven at ``lengths_mm`` (256,) [mm]: ``fit(L_v) - (lo + v / 255 (hi - lo))``."""
    v = np.arange(LEVELS, dtype=np.float64) / (LEVELS - 1)
    target = fit.ogcd_min + v * (fit.ogcd_max - fit.ogcd_min)
    return fit(np.asarray(lengths_mm, dtype=np.float64)) - target


@dataclass(frozen=True, eq=False)
class GroupingError:
    """What grouping costs, measured on checked groups (arrays of shape (K,)).

    ``groups`` checked group indices; ``pixels`` the member traced (farthest from the
    representative); ``angle_deg`` its angle to the representative; ``max_ogcd_diff`` the
    largest |OGCD(member) - OGCD(representative)| over the lengths [dE00] and
    ``ogcd_diff_stderr`` its Monte Carlo standard error there (independent-error bound);
    ``table_error`` the largest deviation from linear OGCD [dE00] of the member driven by the
    representative's table, ``own_table_error`` with a table of its own.

    The difference splits in two (each the largest over lengths, dE00), by also tracing the
    member from the representative's view direction: ``geometry_diff`` = member from its own
    direction vs from the representative's (what the tolerance controls), ``pixel_diff`` =
    member vs representative from the same direction (its own tuft layout, neighbours and
    position; no grouping tolerance removes it). NaN when not decomposed.
    """

    groups: np.ndarray
    pixels: np.ndarray
    angle_deg: np.ndarray
    max_ogcd_diff: np.ndarray
    ogcd_diff_stderr: np.ndarray
    table_error: np.ndarray
    own_table_error: np.ndarray
    geometry_diff: np.ndarray
    pixel_diff: np.ndarray

    def summary(self) -> GroupingSummary:
        """Worst and mean values (dE00, deg) for reports (JSON-safe: the geometry and pixel
        parts only when decomposed)."""
        if len(self.groups) == 0:
            return {"groups_checked": 0}
        out: GroupingSummary = {
            "groups_checked": int(len(self.groups)),
            "max_angle_deg": float(self.angle_deg.max()),
            "max_ogcd_diff": float(self.max_ogcd_diff.max()),
            "mean_ogcd_diff": float(self.max_ogcd_diff.mean()),
            "max_table_error": float(self.table_error.max()),
            "max_own_table_error": float(self.own_table_error.max()),
            "max_added_table_error": float((self.table_error - self.own_table_error).max())}
        if np.all(np.isfinite(self.geometry_diff)):
            out["max_geometry_diff"] = float(np.max(self.geometry_diff))
            out["max_pixel_diff"] = float(np.max(self.pixel_diff))
        return out


@dataclass(frozen=True, eq=False)
class DisplaySimulation:
    """Characteristics of every pixel of a display for one viewer.

    ``curves`` one :class:`SimulatedCurve` per group (its representative's); pixel ``i``'s
    characteristic is ``curves[groups.labels[i]]``. ``grouping_error`` is None when no group was
    checked. ``seconds``: summed ``compile``, ``trace``, ``colour`` and wall ``total``.
    """

    geometry: PixelGeometry
    groups: PixelGroups
    curves: list[SimulatedCurve]
    grouping_error: GroupingError | None
    seconds: dict[str, float] = field(default_factory=dict)

    @property
    def lengths_mm(self) -> np.ndarray:
        """The simulated green lengths [mm]."""
        return self.curves[0].lengths_mm

    def pixel_ogcd(self) -> np.ndarray:
        """(N, n_lengths) OGCD of every pixel [dE00]."""
        return np.stack([c.ogcd for c in self.curves])[self.groups.labels]

    def pixel_stderr(self) -> np.ndarray:
        """(N, n_lengths) Monte Carlo standard error of :meth:`pixel_ogcd` [dE00]."""
        return np.stack([c.ogcd_stderr for c in self.curves])[self.groups.labels]

    def group_characteristic(self, g: int) -> Characteristic:
        """Group ``g``'s characteristic (lengths mm, OGCD dE00 with standard errors)."""
        return curve_characteristic(self.curves[g])


def _pick_checks(groups: PixelGroups, check_groups: int) -> np.ndarray:
    multi = np.flatnonzero((groups.sizes > 1) & (groups.farthest != groups.representatives))
    order = multi[np.argsort(-groups.spread_deg[multi], kind="stable")]
    return order if check_groups < 0 else order[:check_groups]


def simulate_display(renderer, display, lighting, viewer, lengths_mm: np.ndarray, settings, *,
                     eye: str = "world", tolerance_deg: float = 2.0,
                     distance_tolerance: float = 0.1, by_neighbours: bool = True,
                     target_stderr: float | None = None, check_groups: int = 4, ccm=None,
                     spectral=None, decompose: bool | None = None,
                     geometry: PixelGeometry | None = None,
                     progress: Callable[[int, int], None] | None = None) -> DisplaySimulation:
    """Trace one representative pixel per viewing-geometry group of ``display``.

    ``viewer``: a ``Viewpoint`` (h cm, d m, theta deg; see :func:`pixel_geometry` for ``eye``),
    or pass ``geometry`` directly (e.g. :func:`geometry_from_eye`). ``lengths_mm``: green
    lengths [mm], first = reference. ``settings``: ``RenderSettings``; every group is traced
    with the same seed (common random numbers across pixels). ``target_stderr`` [dE00]: add
    replicates per group until its largest OGCD standard error is at most this.
    ``check_groups``: also trace the farthest member of this many multi-pixel groups (widest
    first; -1 = all) to measure the grouping error, and with ``decompose`` once more from the
    representative's direction (see :class:`GroupingError`); None (default): only when every
    pixel has its own tuft layout (with a shared one the pixel part is too small to be worth a
    trace per check: docs/calibration.md). ``progress(done, total)`` counts traces.
    ``spectral``: :func:`~grassd.daemon.core.calibration.simulation.simulate_curve`'s.
    """
    t0 = time.perf_counter()
    if decompose is None:
        decompose = not display.same_layout
    geo = geometry if geometry is not None else pixel_geometry(display, viewer, eye)
    if geo.n_pixels != display.rows * display.cols:
        raise DisplaySimulationError(f"geometry has {geo.n_pixels} pixels, the display "
                                     f"{display.rows * display.cols}")
    groups = group_pixels(geo, tolerance_deg, distance_tolerance, by_neighbours)
    checks = _pick_checks(groups, check_groups)
    total = groups.n_groups + len(checks) * (2 if decompose else 1)
    done = 0

    def trace(i: int, view_of: int | None = None) -> SimulatedCurve:
        nonlocal done
        vp = geo.viewpoint(int(i if view_of is None else view_of))
        curve = simulate_curve(renderer, display, lighting, vp, lengths_mm,
                               settings, ccm=ccm, pixel_index=int(i),
                               target_stderr=target_stderr, spectral=spectral)
        done += 1
        if progress:
            progress(done, total)
        return curve

    curves = [trace(i) for i in groups.representatives]
    check_curves = [trace(groups.farthest[g]) for g in checks]
    swapped = [trace(groups.farthest[g], view_of=groups.representatives[g])
               for g in checks] if decompose else []
    err = _grouping_error(groups, curves, checks, check_curves, swapped) if len(checks) else None
    seconds = {k: float(sum(c.seconds.get(k, 0.0) for c in curves + check_curves + swapped))
               for k in ("compile", "trace", "colour")}
    seconds["total"] = time.perf_counter() - t0
    return DisplaySimulation(geometry=geo, groups=groups, curves=curves, grouping_error=err,
                             seconds=seconds)


def curve_characteristic(c: SimulatedCurve) -> Characteristic:
    """The characteristic of a simulated curve (lengths mm, OGCD dE00), its Monte Carlo
    standard errors floored (:func:`grassd.calib.characteristic.floor_stderr`) so that every
    point keeps a finite fit weight."""
    return Characteristic(c.lengths_mm, c.ogcd, floor_stderr(c.ogcd_stderr))


def _fit(c: SimulatedCurve) -> FittedCharacteristic:
    return fit_characteristic(curve_characteristic(c))


def _grouping_error(groups: PixelGroups, curves: list[SimulatedCurve], checks: np.ndarray,
                    check_curves: list[SimulatedCurve], swapped: list[SimulatedCurve]
                    ) -> GroupingError:
    rep_ogcd = np.stack([curves[g].ogcd for g in checks])
    rep_se = np.stack([curves[g].ogcd_stderr for g in checks])
    mem_ogcd = np.stack([c.ogcd for c in check_curves])
    mem_se = np.stack([c.ogcd_stderr for c in check_curves])
    diff = np.abs(mem_ogcd - rep_ogcd)
    at = diff.argmax(axis=1)
    rows = np.arange(len(checks))
    table_err, own_err = [], []
    for g, mc in zip(checks, check_curves, strict=True):  # one loop per checked group
        mfit = _fit(mc)
        rep_table = build_length_table(_fit(curves[g])).lengths_mm
        own_table = build_length_table(mfit).lengths_mm
        table_err.append(np.abs(table_deviation(mfit, rep_table)).max())
        own_err.append(np.abs(table_deviation(mfit, own_table)).max())
    return GroupingError(
        groups=checks, pixels=groups.farthest[checks], angle_deg=groups.spread_deg[checks],
        max_ogcd_diff=diff[rows, at], ogcd_diff_stderr=np.hypot(rep_se, mem_se)[rows, at],
        table_error=np.asarray(table_err), own_table_error=np.asarray(own_err),
        geometry_diff=np.array([np.abs(m.ogcd - w.ogcd).max() for m, w in
                                zip(check_curves, swapped, strict=True)]) if swapped
        else np.full(len(checks), np.nan),
        pixel_diff=np.abs(np.stack([w.ogcd for w in swapped]) - rep_ogcd).max(axis=1)
        if swapped else np.full(len(checks), np.nan))


# --------------------------------------------------------------------------- tables


@dataclass(frozen=True, eq=False)
class DisplayTables:
    """8-bit length tables for a whole display.

    ``granularity`` "pixel" | "controller" | "global"; ``names`` one per table; ``tables`` the
    :class:`LengthTable` of each; ``unit_of_pixel`` (N,) which table drives each pixel (-1: no
    controller owns the pixel; it gets the global table); ``pixel_lengths_um`` (N, 256) uint16
    [um]; ``pixel_error`` (N,) the largest deviation of each pixel's OGCD from the linear ramp of
    its own range under its table [dE00], measured on its group's characteristic (what grouping
    adds is :class:`GroupingError`); ``pixel_ogcd_range`` (N,) its fitted OGCD range.
    """

    granularity: str
    names: list[str]
    tables: list[LengthTable]
    unit_of_pixel: np.ndarray
    pixel_lengths_um: np.ndarray
    pixel_error: np.ndarray
    pixel_ogcd_range: np.ndarray

    def summary(self) -> dict[str, float | int | str]:
        """Counts and worst/mean pixel errors for reports."""
        return {"granularity": self.granularity, "tables": len(self.tables),
                "max_pixel_error": float(self.pixel_error.max()),
                "mean_pixel_error": float(self.pixel_error.mean()),
                "min_ogcd_range": float(self.pixel_ogcd_range.min()),
                "max_ogcd_range": float(self.pixel_ogcd_range.max())}


def mean_characteristic(sim: DisplaySimulation, pixels: np.ndarray) -> Characteristic:
    """Pixel-weighted mean characteristic of ``pixels`` (mean of the groups' curves weighted
    by how many of the pixels each group holds; standard error: the weighted mean error, a
    bound since the groups share random numbers)."""
    w = np.bincount(sim.groups.labels[pixels], minlength=sim.groups.n_groups).astype(float)
    w /= w.sum()
    ogcd = w @ np.stack([c.ogcd for c in sim.curves])
    se = w @ np.stack([c.ogcd_stderr for c in sim.curves])
    return Characteristic(sim.lengths_mm, ogcd, floor_stderr(se))


def controller_pixels(controllers: Sequence, pixel_count: int) -> list[np.ndarray]:
    """Pixel index arrays of ``ControllerConfig``-like objects (``.pixels``: inclusive ranges)."""
    out = []
    for c in controllers:
        idx = np.concatenate([np.arange(a, b + 1) for a, b in c.pixels]) if c.pixels else \
            np.zeros(0, np.int64)
        if idx.size and (idx.min() < 0 or idx.max() >= pixel_count):
            raise DisplaySimulationError(f"controller {getattr(c, 'name', '?')} drives pixel "
                                         f"{int(idx.max())}, the display has {pixel_count}")
        out.append(idx)
    return out


def build_display_tables(sim: DisplaySimulation, granularity: str = "pixel", *,
                         controllers: Sequence[np.ndarray] | None = None,
                         controller_names: Sequence[str] | None = None) -> DisplayTables:
    """Length tables per pixel, per controller or one global table (see module docstring).

    ``controllers``: pixel index arrays, one per controller (granularity "controller"); pixels
    that no controller owns get the global table. Per-pixel tables cost one fit per group.
    """
    if granularity not in GRANULARITIES:
        raise DisplaySimulationError(f"table granularity must be one of {GRANULARITIES}, got "
                                     f"{granularity!r}")
    n = sim.geometry.n_pixels
    labels = sim.groups.labels
    fits = [_fit(c) for c in sim.curves]  # one per group
    if granularity == "pixel":
        tables = [build_length_table(f) for f in fits]
        names = [f"group {g} (pixel {int(p)})" for g, p in enumerate(sim.groups.representatives)]
        unit = labels.copy()
    elif granularity == "global":
        tables = [build_length_table(mean_characteristic(sim, np.arange(n)))]
        names, unit = ["global"], np.zeros(n, np.int64)
    else:
        if not controllers:
            raise DisplaySimulationError("granularity \"controller\" needs the controllers' "
                                         "pixel sets")
        unit = np.full(n, -1, np.int64)
        tables, names = [], []
        for k, pix in enumerate(controllers):
            pix = np.asarray(pix, np.int64)
            if pix.size == 0:
                continue
            if np.any(unit[pix] >= 0):
                raise DisplaySimulationError(f"controller {k} shares pixels with another one")
            unit[pix] = len(tables)
            tables.append(build_length_table(mean_characteristic(sim, pix)))
            names.append(controller_names[k] if controller_names else f"controller {k}")
        if np.any(unit < 0):
            unit[unit < 0] = len(tables)
            tables.append(build_length_table(mean_characteristic(sim, np.arange(n))))
            names.append("global (pixels without a controller)")
    lengths_um = np.stack([t.lengths_um for t in tables])[unit]
    ranges = np.array([f.ogcd_range for f in fits])
    return DisplayTables(granularity=granularity, names=names, tables=tables,
                         unit_of_pixel=unit, pixel_lengths_um=lengths_um,
                         pixel_error=_pixel_errors(fits, labels, tables, unit),
                         pixel_ogcd_range=ranges[labels])


def _pixel_errors(fits: Sequence[FittedCharacteristic], labels: np.ndarray,
                  tables: Sequence[LengthTable], unit: np.ndarray) -> np.ndarray:
    """(N,) error of pixel i = fits[labels[i]] driven by tables[unit[i]]; one evaluation per
    (characteristic, table) pair actually used, then spread onto the pixels."""
    pairs, inv = np.unique(np.stack([labels, unit], axis=1), axis=0, return_inverse=True)
    pair_err = np.array([np.abs(table_deviation(fits[g], tables[u].lengths_mm)).max()
                         for g, u in pairs])
    return pair_err[inv.reshape(-1)]


def errors_on(reference: DisplaySimulation, tables: DisplayTables) -> np.ndarray:
    """(N,) largest deviation [dE00] of every pixel's OGCD from the linear ramp of its own
    range when driven by its table in ``tables``, the pixel's characteristic taken from
    ``reference`` (the same display and viewer simulated otherwise, e.g. per pixel with
    tolerance 0). Against a per-pixel reference, minus that reference's own
    ``build_display_tables(reference, "pixel").pixel_error``, this is what grouping adds, over
    every pixel rather than the checked groups of :class:`GroupingError` (Monte Carlo noise of
    both runs included)."""
    if reference.geometry.n_pixels != len(tables.unit_of_pixel):
        raise DisplaySimulationError(f"reference has {reference.geometry.n_pixels} pixels, the "
                                     f"tables {len(tables.unit_of_pixel)}")
    fits = [_fit(c) for c in reference.curves]
    return _pixel_errors(fits, reference.groups.labels, tables.tables, tables.unit_of_pixel)


# --------------------------------------------------------------------------- configuration


def combine_viewpoints(sims: Sequence[DisplaySimulation], weights: Sequence[float]
                       ) -> DisplaySimulation:
    """One display characteristic from several viewers: every pixel's OGCD is the weighted mean
    of its OGCD for each viewer [dE00] (standard error: the weighted mean of the errors, a bound
    since the traces share random numbers). Pixels that share a group for every viewer share
    the combined curve, so tables still cost one fit per combined group."""
    if not sims or len(sims) != len(weights):
        raise DisplaySimulationError("give one weight per display simulation")
    w = np.asarray(weights, np.float64)
    if np.any(w < 0) or w.sum() <= 0:
        raise DisplaySimulationError("viewpoint weights must be >= 0 and not all 0")
    w = w / w.sum()
    if len(sims) == 1:
        return sims[0]
    stacked = np.stack([s.groups.labels for s in sims], axis=1)
    _, first, labels = np.unique(stacked, axis=0, return_index=True, return_inverse=True)
    labels = labels.reshape(-1)
    curves = []
    for p in first:  # one combined curve per combined group
        parts = [s.curves[s.groups.labels[p]] for s in sims]
        ogcd = sum(wk * c.ogcd for wk, c in zip(w, parts, strict=True))
        se = sum(wk * c.ogcd_stderr for wk, c in zip(w, parts, strict=True))
        curves.append(dataclasses.replace(parts[0], ogcd=ogcd, ogcd_stderr=se))
    spread = np.max([s.groups.spread_deg[s.groups.labels[first]] for s in sims], axis=0)
    groups = PixelGroups(labels=labels, representatives=first, spread_deg=spread,
                         farthest=first, tolerance_deg=sims[0].groups.tolerance_deg)
    seconds = {k: float(sum(s.seconds.get(k, 0.0) for s in sims))
               for k in ("compile", "trace", "colour", "total")}
    return DisplaySimulation(geometry=sims[0].geometry, groups=groups, curves=curves,
                             grouping_error=None, seconds=seconds)


def display_tables_for_config(renderer, cfg, lighting, lengths_mm: np.ndarray, settings, *,
                              target_stderr: float | None = None, ccm=None, spectral=None,
                              progress: Callable[[int, int], None] | None = None
                              ) -> tuple[DisplayTables, list[DisplaySimulation]]:
    """Tables for a daemon ``Config``: its display (``[display]``), every ``[[viewpoints]]``
    entry as a viewer (weights), grouping and granularity from ``[tables]``, controllers'
    pixel sets from ``[[controllers]]``. Returns the tables and each viewer's simulation (with
    its grouping error)."""
    from grassd.sim.scene import Viewpoint

    display = display_spec_for_config(cfg)
    t = cfg.tables
    sims = []
    for k, v in enumerate(cfg.viewpoints):
        def step(done: int, total: int, k: int = k) -> None:
            if progress:
                progress(k * total + done, len(cfg.viewpoints) * total)

        sims.append(simulate_display(
            renderer, display, lighting, Viewpoint(v.h_cm, v.d_m, v.theta_deg), lengths_mm,
            settings, eye=t.eye, tolerance_deg=t.group_tolerance_deg,
            distance_tolerance=t.distance_tolerance, target_stderr=target_stderr,
            check_groups=t.check_groups, ccm=ccm, spectral=spectral, progress=step))
    combined = combine_viewpoints(sims, [v.weight for v in cfg.viewpoints])
    controllers = controller_pixels(cfg.controllers, display.rows * display.cols)
    tables = build_display_tables(combined, t.granularity, controllers=controllers,
                                  controller_names=[c.name for c in cfg.controllers])
    return tables, sims
