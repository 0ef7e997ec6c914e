"""Whole-display calibration runs: a table per controller or per pixel, or from an audience.

:meth:`grassd.daemon.calibration.calibrate.Calibrator.run` comes here when ``[tables] granularity``
is "controller" or "pixel", or an ``[audience]`` region is configured (granularity "global" without
``[audience]`` stays the one-table run of :mod:`grassd.daemon.calibration.calibrate`). The pieces
are those of the API; nothing here re-implements them:

* **From [[viewpoints]]** (no ``[audience]``): every viewpoint is a viewer of the whole display
  (``[display]`` rows x cols, neighbours present, each pixel seen from its own direction, pixels
  grouped by viewing geometry; :func:`grassd.daemon.calibration.display_model.display_tables_for_config`),
  the viewers' characteristics averaged with their weights, then one table per controller (its
  pixels' mean characteristic) or per pixel (per geometry group, shared by its members)
  (:func:`grassd.daemon.calibration.display_model.build_display_tables`).
* **From [audience]**: the region is sampled
  (:func:`grassd.daemon.calibration.audience.region_from_config`). Granularity "global": the
  display's centre pixel from every sampled eye and the table that minimises the mean (or worst)
  deviation from linear OGCD over the eyes
  (:func:`grassd.daemon.calibration.audience.region_table`). "controller"/"pixel": the whole display
  is traced from every eye (:func:`grassd.daemon.calibration.display_model.simulate_display` with
  :func:`grassd.daemon.calibration.display_model.geometry_from_eye`); each controller (its pixels' mean
  characteristic for that eye) or each pixel group (groups combined over the eyes,
  :func:`grassd.daemon.calibration.display_model.combine_viewpoints`) gets the region table over the eyes.
  The grouping error (``[tables] check_groups``) is measured from the first sampled eye only.

Each run also gives a *display-wide* table (all pixels' mean characteristic, or the region table
of it): it is the run's table in history and the one a controller gets when the run holds no
table of its own for it (e.g. one added to the config afterwards). Per-controller tables are
keyed by controller name (``port#address``); a "pixel" table of a controller has shape
(n_pixels, 256), its rows in the order of the controller's ``pixels`` ranges (row i drives the
controller's i-th pixel, PROTOCOL.md section 3).

Checks, as for the global run: every unit's characteristic passes
:func:`grassd.daemon.calibration.calibrate.check_shape`; every table passes
:func:`grassd.daemon.calibration.calibrate.check_table` (monotone, within 0..green_max, and no entry
jumps more than ``max_jump_mm`` from the same controller's previous table, or from the previous
display-wide table when the shapes differ, unless forced). Then the closed loop, up to
``max_rounds`` rounds as in the global run (:func:`closed_loop_check`): every pixel group's
representative (a group whose members two tables drive is checked once per table,
:meth:`Viewers.split_by_table`) is re-simulated by every viewer at its own table's lengths for
``check_levels`` levels (a fresh seed per round) and its weighted OGCD is compared with the
linear target; a unit (controller or pixel group) whose pixels deviate by more than
``target_de00`` gets the round's points added to its fit and a new table (:func:`refine_unit`),
which passes the table checks again, and the next round re-checks. ``max_dev_de00`` and
``r2_closed_loop`` are the worst group's in the last round. Tables from ``[audience]`` are
checked in one round and not refined: a region table is not the inverse of one characteristic.
The fits' own deviation from linear (``max_fit_dev_de00``, largest over the unit's pixels and
sampled eyes) is reported beside it.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from grassd.calib.ccm import ColourCorrection
from grassd.calib.characteristic import (
    Characteristic,
    FittedCharacteristic,
    fit_characteristic,
    floor_stderr,
)
from grassd.calib.length_table import LEVELS, build_length_table, r_squared
from grassd.daemon.calibration.audience import (
    centre_pixel,
    evaluate_table,
    region_from_config,
    region_table,
    simulate_region,
)
from grassd.daemon.calibration.calibrate import (
    _finite_or_none,
    check_levels,
    check_shape,
    check_table,
    pooled_characteristic,
)
from grassd.daemon.calibration.display_model import (
    capacity_for,
    combine_viewpoints,
    controller_pixels,
    curve_characteristic,
    display_spec_for_config,
    display_tables_for_config,
    geometry_from_eye,
    mean_characteristic,
    simulate_display,
    table_deviation,
)
from grassd.daemon.calibration.simulation import simulate_curve
from grassd.daemon.errors import CalibrationRejected, RunInterrupted
from grassd.firmware_proto.tables import as_table_array, table_crc

if TYPE_CHECKING:
    from grassd.daemon.calibration.calibrate import Calibrator
    from grassd.daemon.store.ingest import CheckerPhoto
    from grassd.sim.light_input import LightInput

Progress = Callable[[str], None]
log = logging.getLogger(__name__)


@dataclass(frozen=True, eq=False)
class UnitTable:
    """One table of a display run and what it does.

    ``name``: the controller name, "group g (pixel p)" or "display"; ``pixels`` the display
    pixel indices it drives (row-major); ``lengths_um`` (256,) uint16 [um];
    ``characteristic`` the unit's mean characteristic over its viewers (lengths mm, OGCD dE00);
    ``max_error``/``mean_error`` the largest / mean |deviation from linear OGCD| under the table
    over the unit's pixels (each with its own characteristic), and from [audience] over the
    sampled eyes too [dE00] (the display-wide table of a controller/pixel run: over the eyes
    of the all-pixel mean; from [[viewpoints]]: not measured, NaN);
    ``r2_before``/``r2_after`` R^2 of the fitted OGCD vs level with linear lengths / the table;
    ``refined_rounds``: closed-loop rounds whose points were added to the fit behind the table
    (:func:`refine_unit`: every round up to its last refinement; ``characteristic`` stays the
    first simulation's).
    """

    name: str
    pixels: NDArray[np.int64]
    lengths_um: NDArray[np.uint16]
    characteristic: Characteristic
    max_error: float
    mean_error: float
    r2_before: float
    r2_after: float
    ogcd_range: float
    loop_max_dev: float = float("nan")
    loop_r2: float = float("nan")
    refined_rounds: int = 0


@dataclass(frozen=True, eq=False)
class LoopCheck:
    """One closed-loop round of a display run: the representative of every pixel group
    (``representatives`` (G,), ``labels`` (N,) group of each pixel) re-simulated by every
    viewer at its own table's lengths for ``levels`` (L,) (``lengths_mm`` (G, L)); ``ogcd``
    (G, L) the viewers' weighted mean OGCD [dE00] and ``ogcd_stderr`` (G, L) the same mean of
    their standard errors (a bound: the viewers share random numbers); ``target`` (G, L) =
    level / 255 x OGCD(255); ``max_dev`` (G,) the largest |ogcd - target| [dE00]; ``r2`` (G,)
    R^2 of OGCD vs level; ``round`` its number (1 = the first tables)."""

    levels: NDArray[np.int64]
    representatives: NDArray[np.int64]
    labels: NDArray[np.int64]
    lengths_mm: NDArray[np.float64]
    ogcd: NDArray[np.float64]
    target: NDArray[np.float64]
    max_dev: NDArray[np.float64]
    r2: NDArray[np.float64]
    ogcd_stderr: NDArray[np.float64]
    round: int = 1

    def pixel_dev(self) -> NDArray[np.float64]:
        """(N,) every pixel's closed-loop deviation (its group's) [dE00]."""
        return self.max_dev[self.labels]

    def report(self) -> dict[str, Any]:
        """JSON-ready arrays."""
        return {"round": self.round, "levels": self.levels.tolist(),
                "pixels": self.representatives.tolist(),
                "lengths_mm": self.lengths_mm.tolist(), "ogcd_de00": self.ogcd.tolist(),
                "ogcd_stderr_de00": self.ogcd_stderr.tolist(),
                "target_de00": self.target.tolist(), "max_dev_de00": self.max_dev.tolist(),
                "r2": self.r2.tolist()}


@dataclass
class DisplayCalibrationResult:
    """A display run: tables per controller (``controller_tables``, name -> (256,) or
    (n_pixels, 256) uint16 um), the display-wide table (:attr:`lengths_um`) and the units
    behind them. ``source`` is "viewpoints" or "audience"; ``shape`` (rows, cols)."""

    granularity: str
    source: str
    shape: tuple[int, int]
    table_um: NDArray[np.uint16]
    controller_tables: dict[str, NDArray[np.uint16]]
    units: list[UnitTable]
    unit_of_pixel: NDArray[np.int64]
    ccm: ColourCorrection | None
    ccm_source: str
    lighting_notes: tuple[str, ...]
    grouping: dict[str, Any] | None = None
    region: dict[str, Any] | None = None
    loop_rounds: list[LoopCheck] = field(default_factory=list)
    seconds: dict[str, float] = field(default_factory=dict)
    max_step_um: int | None = None

    @property
    def loop(self) -> LoopCheck | None:
        """The last closed-loop round (it checked the tables pushed); None without one."""
        return self.loop_rounds[-1] if self.loop_rounds else None

    @property
    def lengths_um(self) -> NDArray[np.uint16]:
        """The display-wide table (256,) uint16 [um] (the run's table in history)."""
        return self.table_um

    def controller_crcs(self) -> dict[str, int]:
        """CRC-32/ISO-HDLC of every controller's table, as the controller reports it."""
        return {k: table_crc(as_table_array(v)) for k, v in self.controller_tables.items()}

    def metrics(self, r2_goal: float = 0.999, target_de00: float = 0.5) -> dict[str, Any]:
        """Summary numbers (dE00): R^2 and deviation of the worst pixel group in the closed
        loop, and of the worst unit in the fits (``*_fit*``)."""
        r2_after = min(u.r2_after for u in self.units)
        fit_worst = max(u.max_error for u in self.units)
        loop = self.loop
        r2 = float(loop.r2.min()) if loop is not None else r2_after
        worst = float(loop.max_dev.max()) if loop is not None else fit_worst
        se = [float(np.mean(u.characteristic.ogcd_stderr)) for u in self.units
              if u.characteristic.ogcd_stderr is not None]
        return {
            "granularity": self.granularity, "table_source": self.source,
            "check": "closed loop" if loop is not None else "fit",
            "tables": len(self.units), "controllers": len(self.controller_tables),
            "r2_before": min(u.r2_before for u in self.units),
            "r2_after_fit": r2_after,
            "r2_closed_loop": float(loop.r2.min()) if loop is not None else None,
            "r2_goal": r2_goal, "r2_goal_met": bool(r2 >= r2_goal),
            "max_dev_de00": worst, "max_dev_goal_de00": target_de00,
            "max_dev_goal_met": bool(worst <= target_de00),
            "max_fit_dev_de00": fit_worst,
            "mean_fit_dev_de00": float(np.mean([u.mean_error for u in self.units])),
            "rounds": len(self.loop_rounds),
            "refined_tables": sum(u.refined_rounds > 0 for u in self.units),
            "ogcd_range_de00": min(u.ogcd_range for u in self.units),
            "mean_ogcd_stderr_de00": float(np.mean(se)) if se else None,
            "ccm_source": self.ccm_source,
            "ccm_mean_de00": _finite_or_none(self.ccm.mean_de00) if self.ccm else None,
            "ccm_max_de00": _finite_or_none(self.ccm.max_de00) if self.ccm else None,
            "max_step_from_last_um": self.max_step_um,
            "grouping": self.grouping, "region": self.region,
            "seconds": dict(self.seconds),
        }

    def report(self) -> dict[str, Any]:
        """A JSON-serialisable report (arrays as lists), with every controller's table CRC."""
        crcs = self.controller_crcs()
        return {
            "granularity": self.granularity, "table_source": self.source,
            "display_shape": list(self.shape),
            "table_um": self.lengths_um.tolist(),
            "controller_tables": {
                k: {"table_crc": crcs[k], "shape": list(v.shape), "lengths_um": v.tolist()}
                for k, v in self.controller_tables.items()},
            "unit_of_pixel": self.unit_of_pixel.tolist(),
            "units": [
                {"name": u.name, "pixels": u.pixels.tolist(), "lengths_um": u.lengths_um.tolist(),
                 "lengths_mm": u.characteristic.lengths_mm.tolist(),
                 "ogcd_de00": u.characteristic.ogcd.tolist(),
                 "ogcd_stderr_de00": None if u.characteristic.ogcd_stderr is None
                 else u.characteristic.ogcd_stderr.tolist(),
                 "max_error_de00": u.max_error, "mean_error_de00": u.mean_error,
                 "r2_before": u.r2_before, "r2_after_fit": u.r2_after,
                 "ogcd_range_de00": u.ogcd_range,
                 "closed_loop_max_dev_de00": _finite_or_none(u.loop_max_dev),
                 "refined_rounds": u.refined_rounds,
                 "closed_loop_r2": _finite_or_none(u.loop_r2)}
                for u in self.units],
            "closed_loop": None if self.loop is None else self.loop.report(),
            "closed_loop_rounds": [
                {"round": lp.round, "max_dev_de00": float(lp.max_dev.max()),
                 "r2_min": float(lp.r2.min())} for lp in self.loop_rounds],
            "grouping": self.grouping, "region": self.region,
            "ccm": None if self.ccm is None else {
                "source": self.ccm_source, "method": self.ccm.method,
                "matrix": self.ccm.matrix.tolist()},
            "lighting_notes": list(self.lighting_notes),
        }

    def figure(self) -> Any:
        """A matplotlib Figure: unit characteristics, unit tables, worst error per pixel."""
        from matplotlib.figure import Figure  # only when plotting

        fig = Figure(figsize=(12, 4), dpi=100)
        ax1, ax2, ax3 = fig.subplots(1, 3)
        many = len(self.units) > 12
        for u in self.units:
            c = u.characteristic
            ax1.plot(c.lengths_mm, c.ogcd, "-", lw=0.5 if many else 1.0,
                     label=None if many else u.name)
            ax2.plot(np.arange(LEVELS), u.lengths_um / 1000.0, "-",
                     lw=0.5 if many else 1.0, label=None if many else u.name)
        ax2.plot(np.arange(LEVELS), self.lengths_um / 1000.0, "k--", lw=1.0, label="display")
        ax1.set(xlabel="green length (mm)", ylabel="OGCD (dE00)",
                title=f"Characteristics ({self.source})")
        ax2.set(xlabel="8-bit level", ylabel="length (mm)",
                title=f"Tables ({self.granularity})")
        if not many:
            ax1.legend(fontsize=6)
        ax2.legend(fontsize=6)
        if self.loop is not None:
            err, how = self.loop.pixel_dev(), "closed loop"
        else:
            err, how = np.array([u.max_error for u in self.units])[self.unit_of_pixel], "fit"
        im = ax3.imshow(err.reshape(self.shape), cmap="magma_r", origin="upper")
        fig.colorbar(im, ax=ax3, shrink=0.8)
        ax3.set(xlabel="column", ylabel="row", title=f"max |OGCD - linear| (dE00, {how})")
        fig.tight_layout()
        return fig


# --------------------------------------------------------------------------- units


def _r2_pair(fit: FittedCharacteristic, lengths_um: NDArray) -> tuple[float, float]:
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
    r2b, r2a = _r2_pair(fit, lengths_um)
    return UnitTable(name, np.asarray(pixels, np.int64), np.asarray(lengths_um, np.uint16), char,
                     float(max_error), float(mean_error), r2b, r2a, float(fit.ogcd_range))


def _region_unit(name: str, pixels: NDArray, chars: Sequence[Characteristic],
                 objective: str) -> UnitTable:
    """A unit whose table is the region table over one characteristic per sampled eye."""
    t = region_table([fit_characteristic(c) for c in chars], objective)
    return _unit(name, pixels, t.lengths_um, _mean_of(chars), float(t.max_error.max()),
                 float(t.mean_error.mean()))


def _pixel_errors(u: UnitTable, sims: Sequence[Any], pixels: NDArray) -> UnitTable:
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


def _merge_grouping(sims: Sequence[Any]) -> dict | None:
    """Worst of the grouping-error summaries of several display simulations (one per viewer;
    None when none checked a group)."""
    summaries = [s.grouping_error.summary() for s in sims if s.grouping_error is not None]
    done = [s for s in summaries if s.get("groups_checked")]
    if not done:
        return None
    out: dict[str, Any] = {"groups_checked": int(sum(s["groups_checked"] for s in done))}
    for k in done[0]:
        if k.startswith("max_"):
            out[k] = float(max(s[k] for s in done))
    return out


@dataclass(frozen=True, eq=False)
class Viewers:
    """Who looks at the display in a run: one
    :class:`grassd.daemon.calibration.display_model.PixelGeometry` per viewer (a [[viewpoints]] entry or a
    sampled eye) with its ``weights``, and the pixel groups over all viewers (``labels`` (N,),
    ``representatives`` (G,): members of a group are seen alike by every viewer), for the
    closed-loop check; from [[viewpoints]] also every group's viewer-weighted characteristic
    (``group_characteristics``, G), for :func:`refine_unit`."""

    geometries: list[Any]
    weights: NDArray[np.float64]
    labels: NDArray[np.int64]
    representatives: NDArray[np.int64]
    group_characteristics: list[Characteristic] | None = None

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


def _viewpoint_units(cal: Calibrator, renderer: Any, display: Any, lighting: Any,
                     lengths: NDArray, settings: Any, ccm: Any, step: Callable[[int, int], None]
                     ) -> tuple[list[UnitTable], NDArray, UnitTable, dict | None, Viewers]:
    """Units from [[viewpoints]]: (units, unit of every pixel, display-wide unit, grouping,
    viewers)."""
    cfg = cal.cfg
    tables, sims = display_tables_for_config(renderer, cfg, lighting, lengths, settings,
                                             ccm=ccm, progress=step)
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
    return units, tables.unit_of_pixel.copy(), whole, grouping, viewers


def _audience_units(cal: Calibrator, renderer: Any, display: Any, lighting: Any,
                    lengths: NDArray, settings: Any, ccm: Any, step: Callable[[int, int], None]
                    ) -> tuple[list[UnitTable], NDArray, UnitTable, dict | None, dict, Viewers]:
    """Units from [audience]: (units, unit of every pixel, display-wide unit, grouping,
    region summary, viewers)."""
    cfg = cal.cfg
    aud, t = cfg.audience, cfg.tables
    region, samples = region_from_config(aud)
    n = display.rows * display.cols
    everyone = np.arange(n)
    info = {"eyes": int(samples.n), "area_m2": region.area_m2, "h_cm": list(region.h_cm),
            "objective": aud.objective}
    if cfg.tables.granularity == "global":
        curves = simulate_region(renderer, display, lighting, samples, lengths, settings,
                                 ccm=ccm, progress=step)
        chars = [curve_characteristic(c) for c in curves]
        whole = _region_unit("display", everyone, chars, aud.objective)
        # the centre pixel stands for every pixel, as in the table's own simulation
        viewers = Viewers([geometry_from_eye(display, e) for e in samples.eyes_m],
                          np.ones(samples.n), np.zeros(n, np.int64),
                          np.array([centre_pixel(display)], np.int64))
        return [whole], np.zeros(n, np.int64), whole, None, info, viewers
    m = samples.n
    sims: list[Any] = []
    for k, eye in enumerate(samples.eyes_m):
        def eye_step(done: int, total: int, k: int = k) -> None:
            step(k * total + done, m * total)

        sims.append(simulate_display(
            renderer, display, lighting, None, lengths, settings,
            geometry=geometry_from_eye(display, eye), tolerance_deg=t.group_tolerance_deg,
            distance_tolerance=t.distance_tolerance,
            check_groups=t.check_groups if k == 0 else 0,  # grouping error: first eye only
            ccm=ccm, progress=eye_step))
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
    return units, unit, whole, grouping, info, viewers


def closed_loop_check(renderer: Any, display: Any, lighting: Any, viewers: Viewers,
                      pixel_tables_um: NDArray, levels: NDArray, settings: Any, ccm: Any,
                      step: Callable[[int, int], None], round_no: int = 1) -> LoopCheck:
    """Re-simulate every group's representative pixel from every viewer at the lengths its
    table gives ``levels`` (``pixel_tables_um`` (N, 256) [um], first level 0 = the reference
    length), average the viewers' OGCD with their weights and compare it with the linear
    target ``level / 255 x OGCD(255)`` (the check of the global run's closed loop).
    ``settings`` carries the round's own seed. One trace per (group, viewer)."""
    w = viewers.weights / viewers.weights.sum()
    reps = viewers.representatives
    lx = pixel_tables_um[reps][:, levels].astype(np.float64) / 1000.0  # (G, L) mm
    total = len(reps) * len(viewers.geometries)
    ogcd = np.empty_like(lx)
    se = np.empty_like(lx)
    done = 0
    for g, p in enumerate(reps):  # one trace per group and viewer, never per pixel
        ys, es = [], []
        for geo in viewers.geometries:
            c = simulate_curve(renderer, display, lighting, geo.viewpoint(int(p)), lx[g],
                               settings, ccm=ccm, pixel_index=int(p))
            ys.append(c.ogcd)
            es.append(c.ogcd_stderr)
            done += 1
            step(done, total)
        ogcd[g] = w @ np.stack(ys)
        se[g] = w @ np.stack(es)
    target = levels[None, :] / (LEVELS - 1) * ogcd[:, -1:]
    r2 = np.array([r_squared(levels, y) for y in ogcd])
    return LoopCheck(levels=levels, representatives=reps, labels=viewers.labels,
                     lengths_mm=lx, ogcd=ogcd, target=target,
                     max_dev=np.abs(ogcd - target).max(axis=1), r2=r2, ogcd_stderr=se,
                     round=round_no)


def refine_unit(u: UnitTable, loops: Sequence[LoopCheck],
                group_characteristics: Sequence[Characteristic]) -> UnitTable:
    """``u`` with its table rebuilt from its characteristic plus the points of every
    closed-loop round in ``loops`` (its table's lengths at the check levels [mm] and its pixels'
    mean loop OGCD [dE00], weighted by pixel count), as the global run refines its table
    (:meth:`grassd.daemon.calibration.calibrate.Calibrator.run`). The errors are re-measured on the
    unit's pixels' own characteristics (``group_characteristics``, one per loop group); R^2 and the
    OGCD range on the refined fit."""
    groups, counts = np.unique(loops[0].labels[u.pixels], return_counts=True)
    w = counts / counts.sum()
    c = u.characteristic
    se0 = c.ogcd_stderr if c.ogcd_stderr is not None else np.zeros_like(c.ogcd)
    xs, ys, ses = [c.lengths_mm], [c.ogcd], [se0]
    for lp in loops:  # the unit's table drives all its groups: one set of lengths per round
        xs.append(lp.lengths_mm[groups[0]])
        ys.append(w @ lp.ogcd[groups])
        ses.append(w @ lp.ogcd_stderr[groups])
    fit = fit_characteristic(pooled_characteristic(xs, ys, ses))
    table = build_length_table(fit)
    errs = np.array([np.abs(table_deviation(fit_characteristic(group_characteristics[g]),
                                            table.lengths_mm)).max() for g in groups])
    r2b, r2a = _r2_pair(fit, table.lengths_um)
    return replace(u, lengths_um=np.asarray(table.lengths_um, np.uint16),
                   max_error=float(errs.max()), mean_error=float(w @ errs), r2_before=r2b,
                   r2_after=r2a, ogcd_range=float(fit.ogcd_range), refined_rounds=len(loops))


# --------------------------------------------------------------------------- the run


def controller_tables_of(cfg: Any, units: Sequence[UnitTable], unit_of_pixel: NDArray
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


def calibrate_display(cal: Calibrator, light: LightInput, *,
                      checker: CheckerPhoto | None = None,
                      previous_um: NDArray | None = None,
                      previous_tables: Mapping[str, NDArray] | None = None,
                      previous_ccm: NDArray | None = None, force: bool = False,
                      stop: threading.Event | None = None,
                      progress: Progress | None = None) -> DisplayCalibrationResult:
    """A display run for ``cal.cfg`` (see the module docstring); raises
    :class:`~grassd.daemon.errors.CalibrationRejected` for a bad characteristic or table and
    :class:`~grassd.daemon.errors.RunInterrupted` when ``stop`` is set (checked per trace)."""
    from grassd.sim.renderer import Renderer
    from grassd.sim.scene import RenderSettings

    cfg = cal.cfg
    t_start = time.perf_counter()
    lighting, ccm, ccm_source = cal.light_and_ccm(light, checker, previous_ccm, progress)
    d = cfg.display
    display = display_spec_for_config(cfg)
    renderer = Renderer.shared(capacity_for(d.rows * d.cols))
    settings = RenderSettings(samples=cfg.simulation.samples,
                              replicates=cfg.calibration.replicates, seed=cfg.simulation.seed)
    lengths = np.asarray(cfg.simulation.lengths_mm, float)
    source = "viewpoints" if cfg.audience is None else "audience"

    def stepper(what: str) -> Callable[[int, int], None]:
        def step(done: int, total: int) -> None:
            if stop is not None and stop.is_set():
                raise RunInterrupted("calibration stopped (daemon shutting down)")
            if progress:
                progress(f"{what} ({source}, {cfg.tables.granularity} tables): "
                         f"trace {done}/{total}")
        return step

    step = stepper("simulating the display")

    step(0, 1)
    region = None
    if source == "viewpoints":
        units, unit_of_pixel, whole, grouping, viewers = _viewpoint_units(
            cal, renderer, display, lighting, lengths, settings, ccm, step)
    else:
        units, unit_of_pixel, whole, grouping, region, viewers = _audience_units(
            cal, renderer, display, lighting, lengths, settings, ccm, step)
    t_sim = time.perf_counter() - t_start
    viewers = viewers.split_by_table(unit_of_pixel)  # every table checked on its own pixels
    cc = cfg.calibration
    for u in units:  # one check per table (controllers or pixel groups), never per pixel
        try:
            check_shape(u.characteristic.lengths_mm, u.characteristic.ogcd,
                        u.characteristic.ogcd_stderr, cc.max_flat_fraction)
        except CalibrationRejected as exc:
            raise CalibrationRejected(f"{u.name}: {exc}") from None
    green_max = d.green_max_mm
    # the display-wide table is never refined: checked once, the controllers' every round
    whole_step = check_table(whole.lengths_um, green_max, None, cc.max_jump_mm, force,
                             "display-wide table")

    def checked_tables(units: list[UnitTable]) -> tuple[dict[str, NDArray], int | None]:
        tables = controller_tables_of(cfg, units, unit_of_pixel)
        steps = [whole_step]
        for name, table in tables.items():
            prev = None if previous_tables is None else previous_tables.get(name)
            if prev is not None and np.ndim(prev) != 1 and np.shape(prev) != table.shape:
                prev = None  # its pixel count changed: compare with the display-wide table
            steps.append(check_table(table, green_max,
                                     prev if prev is not None else previous_um,
                                     cc.max_jump_mm, force, f"table of controller {name}"))
        known = [s for s in steps if s is not None]
        return tables, max(known) if known else None

    controller_tables, max_step = checked_tables(units)
    # closed loop: the tables as the display will show them, re-simulated with a fresh seed
    # per round; units off the linear target by more than target_de00 get the round's points
    # added to their fit and a new table (from [[viewpoints]]; a region table is not the
    # inverse of one characteristic, so [audience] runs check one round)
    t_loop = time.perf_counter()
    levels = check_levels(cc.check_levels)
    rounds: list[LoopCheck] = []
    for k in range(1, cc.max_rounds + 1):
        pixel_tables = np.stack([u.lengths_um for u in units])[unit_of_pixel]
        loop = closed_loop_check(renderer, display, lighting, viewers, pixel_tables, levels,
                                 replace(settings, seed=settings.seed + 1000 * k), ccm,
                                 stepper(f"closed loop round {k}"), round_no=k)
        rounds.append(loop)
        pixel_dev = loop.pixel_dev()
        off = [i for i, u in enumerate(units)
               if u.pixels.size and pixel_dev[u.pixels].max() > cc.target_de00]
        log.info("display closed loop round %d: max deviation %.3f dE00, %d of %d tables "
                 "above %.2f", k, float(loop.max_dev.max()), len(off), len(units),
                 cc.target_de00)
        if not off or k == cc.max_rounds or viewers.group_characteristics is None:
            break
        for i in off:  # every round so far measured the unit's table of its time
            units[i] = refine_unit(units[i], rounds, viewers.group_characteristics)
        controller_tables, max_step = checked_tables(units)
    pixel_dev = loop.pixel_dev()
    pixel_r2 = loop.r2[loop.labels]
    units = [replace(u, loop_max_dev=float(pixel_dev[u.pixels].max()),
                     loop_r2=float(pixel_r2[u.pixels].min())) if u.pixels.size else u
             for u in units]
    total = time.perf_counter() - t_start
    return DisplayCalibrationResult(
        granularity=cfg.tables.granularity, source=source, shape=(d.rows, d.cols),
        table_um=whole.lengths_um, controller_tables=controller_tables, units=units,
        unit_of_pixel=unit_of_pixel, ccm=ccm, ccm_source=ccm_source,
        lighting_notes=tuple(getattr(lighting, "notes", ())), grouping=grouping, region=region,
        loop_rounds=rounds,
        seconds={"simulate": t_sim, "closed_loop": total - (t_loop - t_start), "total": total},
        max_step_um=max_step)
