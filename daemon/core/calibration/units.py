"""The units of a calibration run: the tables it builds and the pixels each one drives.

A run's *source* says who looks at the display (see :mod:`grassd.daemon.core.calibration.result`):

* :func:`centre_units` (:data:`~grassd.daemon.core.calibration.result.CENTRE`): the centre pixel of
an
  up-to-3 x 3 patch (neighbours shade it as on the real display) from every [[viewpoints]]
  entry, the viewpoints' OGCD averaged with their weights; one unit, one table.
* :func:`viewpoint_units` ("viewpoints"): every [[viewpoints]] entry is a viewer of the whole
  display (``[display]`` rows x cols, each pixel seen from its own direction, pixels grouped by
  viewing geometry; :func:`grassd.daemon.core.calibration.display_model.display_tables_for_config`),
  the viewers' characteristics averaged with their weights, then one table per controller (its
  pixels' mean characteristic) or per pixel (per geometry group, shared by its members)
  (:func:`grassd.daemon.core.calibration.display_model.build_display_tables`).
* :func:`audience_units` ("audience"): the ``[audience]`` region is sampled
  (:func:`grassd.daemon.core.calibration.audience.region_from_config`). Granularity "global": the
  display's centre pixel from every sampled eye and the table that minimises the mean (or worst)
  deviation from linear OGCD over the eyes
  (:func:`grassd.daemon.core.calibration.audience.region_table`). "controller"/"pixel": the whole
  display is traced from every eye
  (:func:`grassd.daemon.core.calibration.display_model.simulate_display` with
  :func:`grassd.daemon.core.calibration.display_model.geometry_from_eye`); each controller (its
  pixels' mean characteristic for that eye) or each pixel group (groups combined over the eyes,
  :func:`grassd.daemon.core.calibration.display_model.combine_viewpoints`) gets the region table
  over the eyes. The grouping error (``[tables] check_groups``) is measured from the first sampled
  eye only.

Each source also gives a *display-wide* unit (all pixels' mean characteristic, or the region
table of it): the run's table in history and the one a controller gets when the run holds no
table of its own for it. Per-controller tables are keyed by controller name (``port#address``);
a "pixel" table of a controller has shape (n_pixels, 256), its rows in the order of the
controller's ``pixels`` ranges (row i drives the controller's i-th pixel, PROTOCOL.md section 3).
Lengths in mm, tables in uint16 um, OGCD in dE00.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, NamedTuple

import numpy as np
from numpy.typing import NDArray

from grassd.calib.characteristic import (
    Characteristic,
    FittedCharacteristic,
    fit_characteristic,
    floor_stderr,
)
from grassd.calib.length_table import LEVELS, build_length_table, r_squared
from grassd.daemon.core.calibration.audience import (
    centre_pixel,
    evaluate_table,
    region_from_config,
    region_table,
    simulate_region,
)
from grassd.daemon.core.calibration.checks import check_shape, pooled_characteristic
from grassd.daemon.core.calibration.display_model import (
    DisplaySimulation,
    PixelGeometry,
    combine_viewpoints,
    controller_pixels,
    curve_characteristic,
    display_tables_for_config,
    geometry_from_eye,
    mean_characteristic,
    simulate_display,
    table_deviation,
)
from grassd.daemon.core.calibration.result import UnitTable, ViewpointCurve
from grassd.daemon.core.calibration.run_report import (
    GROUPING_MAXIMA,
    GroupingSummary,
    RegionSummary,
)

if TYPE_CHECKING:
    import threading

    from grassd.calib.ccm import ColourCorrection
    from grassd.daemon.core.calibration.calibrate import Calibrator, Progress
    from grassd.daemon.core.calibration.transport import SpectralTransport
    from grassd.daemon.core.config.settings import Config
    from grassd.sim.lighting import Lighting
    from grassd.sim.renderer import Renderer
    from grassd.sim.scene import DisplaySpec, RenderSettings, Viewpoint


class Units(NamedTuple):
    """What a source gives the run: ``units`` (their tables drive the display),
    ``unit_of_pixel`` (N,) the unit of every traced pixel, ``whole`` the display-wide unit (None:
    the run's one unit is it), ``grouping`` / ``region`` summaries for the report, ``viewers``
    for the closed loop, and a centre-pixel run's per-viewpoint ``curves``."""

    units: list[UnitTable]
    unit_of_pixel: NDArray[np.int64]
    whole: UnitTable | None
    grouping: GroupingSummary | None
    region: RegionSummary | None
    viewers: Viewers
    curves: list[ViewpointCurve]


def r2_pair(fit: FittedCharacteristic, lengths_um: NDArray) -> tuple[float, float]:
    """R^2 of fitted OGCD vs level with linear lengths and with ``lengths_um`` (256,) [um]."""
    levels = np.arange(LEVELS, dtype=np.float64)
    linear = np.linspace(fit.min_length_mm, fit.max_length_mm, LEVELS)
    return (r_squared(levels, fit(linear)),
            r_squared(levels, fit(np.asarray(lengths_um, np.float64) / 1000.0)))


def _mean_of(chars: Sequence[Characteristic]) -> Characteristic:
    """Mean characteristic of ``chars`` (one per sampled eye, same lengths [mm]); error: the
    mean standard error [dE00], floored (:func:`grassd.calib.characteristic.floor_stderr`)."""
    w = np.full(len(chars), 1.0 / len(chars))
    ogcd = w @ np.stack([c.ogcd for c in chars])
    se = w @ np.stack([c.ogcd_stderr for c in chars])
    return Characteristic(chars[0].lengths_mm, ogcd, floor_stderr(se))


def _unit(name: str, pixels: NDArray, lengths_um: NDArray, char: Characteristic,
          max_error: float, mean_error: float) -> UnitTable:
    fit = fit_characteristic(char)
    r2b, r2a = r2_pair(fit, lengths_um)
    return UnitTable(name, np.asarray(pixels, np.int64), np.asarray(lengths_um, np.uint16), char,
                     float(max_error), float(mean_error), r2b, r2a, float(fit.ogcd_range))


def _region_unit(name: str, pixels: NDArray, chars: Sequence[Characteristic],
                 objective: str) -> UnitTable:
    """A unit whose table is the region table over one characteristic per sampled eye."""
    t = region_table([fit_characteristic(c) for c in chars], objective)
    return _unit(name, pixels, t.lengths_um, _mean_of(chars), float(t.max_error.max()),
                 float(t.mean_error.mean()))


def _pixel_errors(u: UnitTable, sims: Sequence[DisplaySimulation], pixels: NDArray
                  ) -> UnitTable:
    """``u`` with its errors measured on its pixels, not on their mean: every (eye, geometry
    group) pair among ``pixels`` driven by ``u``'s table; worst, and mean weighted by pixels."""
    fits, weights = [], []
    for s in sims:  # one entry per eye
        groups, counts = np.unique(s.groups.labels[pixels], return_counts=True)
        fits += [fit_characteristic(s.group_characteristic(int(g))) for g in groups]
        weights.append(counts)
    w = np.concatenate(weights).astype(np.float64)
    ev = evaluate_table(fits, u.lengths_um, weights=w)
    return replace(u, max_error=float(ev.max_error.max()),
                   mean_error=float(w @ ev.mean_error / w.sum()))


def _merge_grouping(sims: Sequence[DisplaySimulation]) -> GroupingSummary | None:
    """Worst of the grouping-error summaries of several display simulations (one per viewer;
    None when none checked a group)."""
    summaries = [s.grouping_error.summary() for s in sims if s.grouping_error is not None]
    done = [s for s in summaries if s.get("groups_checked")]
    if not done:
        return None
    out: GroupingSummary = {"groups_checked": int(sum(s["groups_checked"] for s in done))}
    for k in GROUPING_MAXIMA:
        if k in done[0]:
            out[k] = float(max(s[k] for s in done))
    return out


@dataclass(frozen=True, eq=False)
class Viewers:
    """Who looks at the display in a run: one
    :class:`grassd.daemon.core.calibration.display_model.PixelGeometry` per viewer (a [[viewpoints]]
    entry or a sampled eye) with its ``weights``, and the pixel groups over all viewers
    (``labels`` (N,), ``representatives`` (G,): members of a group are seen alike by every
    viewer), for the closed-loop check; from [[viewpoints]] also every group's viewer-weighted
    characteristic (``group_characteristics``, G), for
    :func:`grassd.daemon.core.calibration.calibrate.refine_unit`. A centre-pixel run's viewers are
    its ``fixed`` viewpoints of the patch's centre pixel, traced with ``layouts`` tuft
    layouts."""

    geometries: list[PixelGeometry]
    weights: NDArray[np.float64]
    labels: NDArray[np.int64]
    representatives: NDArray[np.int64]
    group_characteristics: list[Characteristic] | None = None
    fixed: list[Viewpoint] | None = None
    layouts: int = 1

    def viewpoints_of(self, pixel: int) -> list[Viewpoint]:
        """Every viewer's :class:`grassd.sim.scene.Viewpoint` of ``pixel`` (a centre-pixel
        run's ``fixed`` viewpoints stand for every pixel)."""
        if self.fixed is not None:
            return list(self.fixed)
        return [g.viewpoint(pixel) for g in self.geometries]

    def split_by_table(self, unit_of_pixel: NDArray[np.int64]) -> Viewers:
        """These viewers with every pixel group split where its members are driven by
        different tables (``unit_of_pixel`` (N,)): groups follow viewing geometry, not
        controllers, so a group can span two controllers, and the closed loop must check each
        table on its own pixels. A part keeps the group's representative when it holds it,
        else its first pixel (seen alike, within the grouping tolerance), and the group's
        characteristic."""
        pairs, first, inv = np.unique(np.stack([self.labels, unit_of_pixel], axis=1), axis=0,
                                      return_index=True, return_inverse=True)
        group = pairs[:, 0]
        rep = self.representatives[group]
        reps = np.where(unit_of_pixel[rep] == pairs[:, 1], rep, first).astype(np.int64)
        chars = (None if self.group_characteristics is None
                 else [self.group_characteristics[g] for g in group])
        return replace(self, labels=inv.reshape(-1).astype(np.int64), representatives=reps,
                       group_characteristics=chars)


def viewpoint_units(cal: Calibrator, renderer: Renderer, display: DisplaySpec, lighting: Lighting,
                     lengths: NDArray, settings: RenderSettings, ccm: ColourCorrection | None,
                     spectral: SpectralTransport | None, step: Callable[[int, int], None]
                     ) -> Units:
    """Units from [[viewpoints]], the whole display traced from each (see the module
    docstring)."""
    cfg = cal.cfg
    tables, sims = display_tables_for_config(renderer, cfg, lighting, lengths, settings,
                                             ccm=ccm, spectral=spectral, progress=step)
    combined = combine_viewpoints(sims, [v.weight for v in cfg.viewpoints])
    n = display.rows * display.cols
    err = tables.pixel_error
    units = []
    for k, (name, table) in enumerate(zip(tables.names, tables.tables, strict=True)):
        pix = np.flatnonzero(tables.unit_of_pixel == k)
        char = (combined.group_characteristic(k) if tables.granularity == "pixel"
                else mean_characteristic(combined, pix))
        units.append(_unit(name, pix, table.lengths_um, char, err[pix].max(), err[pix].mean()))
    everyone = np.arange(n)
    char = mean_characteristic(combined, everyone)
    whole = _unit("display", everyone, build_length_table(char).lengths_um, char,
                  np.nan, np.nan)
    grouping = _merge_grouping(sims)
    viewers = Viewers([s.geometry for s in sims],
                      np.array([v.weight for v in cfg.viewpoints], np.float64),
                      combined.groups.labels, combined.groups.representatives,
                      [combined.group_characteristic(g)
                       for g in range(combined.groups.n_groups)])
    return Units(units, tables.unit_of_pixel.copy(), whole, grouping, None, viewers, [])


def audience_units(cal: Calibrator, renderer: Renderer, display: DisplaySpec, lighting: Lighting,
                    lengths: NDArray, settings: RenderSettings, ccm: ColourCorrection | None,
                    spectral: SpectralTransport | None, step: Callable[[int, int], None]
                    ) -> Units:
    """Units from [audience] (see the module docstring)."""
    cfg = cal.cfg
    aud, t = cfg.audience, cfg.tables
    region, samples = region_from_config(aud)
    n = display.rows * display.cols
    everyone = np.arange(n)
    info: RegionSummary = {"eyes": int(samples.n), "area_m2": region.area_m2,
                           "h_cm": list(region.h_cm), "objective": aud.objective}
    if cfg.tables.granularity == "global":
        curves = simulate_region(renderer, display, lighting, samples, lengths, settings,
                                 ccm=ccm, spectral=spectral, progress=step)
        chars = [curve_characteristic(c) for c in curves]
        whole = _region_unit("display", everyone, chars, aud.objective)
        # the centre pixel stands for every pixel, as in the table's own simulation
        viewers = Viewers([geometry_from_eye(display, e) for e in samples.eyes_m],
                          np.ones(samples.n), np.zeros(n, np.int64),
                          np.array([centre_pixel(display)], np.int64))
        return Units([whole], np.zeros(n, np.int64), None, None, info, viewers, [])
    m = samples.n
    sims: list[DisplaySimulation] = []
    for k, eye in enumerate(samples.eyes_m):
        def eye_step(done: int, total: int, k: int = k) -> None:
            step(k * total + done, m * total)

        sims.append(simulate_display(
            renderer, display, lighting, None, lengths, settings,
            geometry=geometry_from_eye(display, eye), tolerance_deg=t.group_tolerance_deg,
            distance_tolerance=t.distance_tolerance,
            check_groups=t.check_groups if k == 0 else 0,  # grouping error: first eye only
            ccm=ccm, spectral=spectral, progress=eye_step))
    whole = _region_unit("display", everyone,
                         [mean_characteristic(s, everyone) for s in sims], aud.objective)
    combined = combine_viewpoints(sims, np.ones(m))
    unit = np.full(n, -1, np.int64)
    units: list[UnitTable] = []
    if t.granularity == "controller":
        for c, pix in zip(cfg.controllers, controller_pixels(cfg.controllers, n), strict=True):
            unit[pix] = len(units)
            u = _region_unit(c.name, pix, [mean_characteristic(s, pix) for s in sims],
                             aud.objective)
            units.append(_pixel_errors(u, sims, pix))
        if np.any(unit < 0):  # pixels without a controller: the display-wide table
            unit[unit < 0] = len(units)
            units.append(whole)
    else:
        for g, p in enumerate(combined.groups.representatives):  # one region table per group
            members = combined.groups.members(g)
            chars = [s.group_characteristic(int(s.groups.labels[p])) for s in sims]
            units.append(_region_unit(f"group {g} (pixel {int(p)})", members, chars,
                                      aud.objective))
        unit = combined.groups.labels.copy()
    grouping = _merge_grouping(sims)
    viewers = Viewers([s.geometry for s in sims], np.ones(m), combined.groups.labels,
                      combined.groups.representatives)
    return Units(units, unit, whole, grouping, info, viewers, [])


def centre_units(cal: Calibrator, display: DisplaySpec, centre: int, lighting: Lighting,
                 lengths: NDArray, seed: int, ccm: ColourCorrection | None,
                 spectral: SpectralTransport | None,
                 stop: threading.Event | None, progress: Progress | None) -> Units:
    """The one unit of a centre-pixel run: pixel ``centre`` of the patch ``display`` from every
    [[viewpoints]] entry (:meth:`Calibrator.simulate`), weighted
    (:meth:`Calibrator.weighted`), shape-checked before its table is built, so that a flat
    light is named as such."""
    curves = cal.simulate(lighting, lengths, seed, ccm, spectral, stop, progress)
    y, se, step_se = cal.weighted(curves)
    if not np.all(np.diff(lengths) > 0):
        step_se = None  # the steps' errors are those of neighbours in increasing length
    check_shape(lengths, y, se, cal.cfg.calibration.max_flat_fraction, step_se)
    char = pooled_characteristic([lengths], [y], [se])
    fit = fit_characteristic(char)
    table = build_length_table(fit)
    err = np.abs(table_deviation(fit, table.lengths_mm))
    n = display.rows * display.cols
    unit = replace(_unit("display", np.arange(n), table.lengths_um, char, err.max(), err.mean()),
                   step_stderr=step_se)
    vps = cal.cfg.viewpoints
    viewers = Viewers([], np.array([v.weight for v in vps], np.float64), np.zeros(n, np.int64),
                      np.array([centre], np.int64), [char],
                      fixed=[cal.viewpoint(v) for v in vps],
                      layouts=cal.cfg.simulation.layouts)
    return Units([unit], np.zeros(n, np.int64), None, None, None, viewers, curves)


def controller_tables_of(cfg: Config, units: Sequence[UnitTable], unit_of_pixel: NDArray
                         ) -> dict[str, NDArray[np.uint16]]:
    """Every configured controller's table: (256,) for granularity "controller" or "global",
    (n_pixels, 256) for "pixel" (rows in the order of the controller's pixel ranges)."""
    n = len(unit_of_pixel)
    stacked = np.stack([u.lengths_um for u in units])
    out = {}
    for c, pix in zip(cfg.controllers, controller_pixels(cfg.controllers, n), strict=True):
        rows = stacked[unit_of_pixel[pix]]
        if cfg.tables.granularity == "pixel":
            out[c.name] = rows
        else:  # one unit drives all the controller's pixels
            out[c.name] = rows[0]
    return out
