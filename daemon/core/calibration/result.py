"""What a calibration run produced: its tables, the units behind them, and its closed loop.

One type for every run (:class:`CalibrationResult`), whatever its source:

* ``"centre pixel"``: one table for the whole display from [[viewpoints]] (``[tables]
  granularity = "global"`` without ``[audience]``): the centre pixel of an up-to-3 x 3 patch is
  simulated from every viewpoint; the run has one unit and no table of its own per controller,
  every controller gets the display-wide table. Its report keeps the form operators' scripts
  read since the first release (``characteristic``, ``viewpoints``, ``closed_loop`` as a list of
  rounds).
* ``"viewpoints"``: the whole display from every [[viewpoints]] entry, a table per controller
  or per pixel group.
* ``"audience"``: from an ``[audience]`` region.

Units: lengths in mm (tables in uint16 um), OGCD in dE00 (CIEDE2000 units).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import TYPE_CHECKING, TypeVar

import numpy as np
from numpy.typing import NDArray

from grassd.calib.ccm import ColourCorrection
from grassd.calib.characteristic import Characteristic
from grassd.calib.length_table import LEVELS
from grassd.daemon.core.calibration.checks import finite_or_none, pooled_characteristic
from grassd.daemon.core.calibration.run_report import (
    CcmMetrics,
    CcmReport,
    CentreReport,
    DisplayMetrics,
    DisplayReport,
    GroupingSummary,
    LoopReport,
    RegionSummary,
    RunMetrics,
    ViewpointCurveReport,
)
from grassd.daemon.core.config.settings import ViewpointConfig
from grassd.firmware_proto.tables import as_table_array, table_crc

if TYPE_CHECKING:
    from matplotlib.figure import Figure

#: the run's source when one table comes from the centre pixel seen from [[viewpoints]]
CENTRE = "centre pixel"

#: a report or metrics, which name the display correction the tables include
_Named = TypeVar("_Named", RunMetrics, DisplayMetrics, CentreReport, DisplayReport)


@dataclass(frozen=True)
class ViewpointCurve:
    """OGCD [dE00] vs length [mm] simulated from one viewpoint (a centre-pixel run's first
    simulation, before the viewpoints are weighted); ``seconds`` its wall time;
    ``step_stderr`` the standard errors of its steps (None when unknown); ``lab`` (n, 3) the
    D50 CIELAB at each length (the colours content is mapped onto; None when unknown)."""

    viewpoint: ViewpointConfig
    lengths_mm: NDArray[np.float64]
    ogcd: NDArray[np.float64]
    ogcd_stderr: NDArray[np.float64]
    seconds: float
    step_stderr: NDArray[np.float64] | None = None
    lab: NDArray[np.float64] | None = None


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
    first simulation's); ``step_stderr`` the standard errors of its characteristic's steps
    when known (a centre-pixel run's, for the shape check), else None.
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
    step_stderr: NDArray[np.float64] | None = None


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

    def report(self) -> LoopReport:
        """JSON-ready arrays."""
        return {"round": self.round, "levels": self.levels.tolist(),
                "pixels": self.representatives.tolist(),
                "lengths_mm": self.lengths_mm.tolist(), "ogcd_de00": self.ogcd.tolist(),
                "ogcd_stderr_de00": self.ogcd_stderr.tolist(),
                "target_de00": self.target.tolist(), "max_dev_de00": self.max_dev.tolist(),
                "r2": self.r2.tolist()}


@dataclass
class CalibrationResult:
    """A run: tables per controller (``controller_tables``, name -> (256,) or (n_pixels, 256)
    uint16 um; empty for a centre-pixel run), the display-wide table (:attr:`lengths_um`) and
    the units behind them. ``source`` is :data:`CENTRE`, "viewpoints" or "audience";
    ``shape`` (rows, cols) of the display traced (the patch of a centre-pixel run);
    ``curves`` a centre-pixel run's per-viewpoint curves."""

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
    grouping: GroupingSummary | None = None
    region: RegionSummary | None = None
    loop_rounds: list[LoopCheck] = field(default_factory=list)
    seconds: dict[str, float] = field(default_factory=dict)
    max_step_um: int | None = None
    curves: list[ViewpointCurve] = field(default_factory=list)
    #: the display measurement whose per-pixel correction the tables include, or None
    correction: str | None = None
    #: how the simulation carried light (``[simulation] transport``)
    transport: str = field(kw_only=True)

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

    def metrics(self, r2_goal: float = 0.999, target_de00: float = 0.5
                ) -> RunMetrics | DisplayMetrics:
        """Summary numbers (dE00): R^2 and deviation of the worst pixel group in the closed
        loop, and of the worst unit in the fits (``*_fit*``). A centre-pixel run gives the
        keys it always gave (:meth:`_centre_metrics`)."""
        if self.source == CENTRE:
            return self._corrected(self._centre_metrics(r2_goal, target_de00))
        r2_after = min(u.r2_after for u in self.units)
        fit_worst = max(u.max_error for u in self.units)
        loop = self.loop
        r2 = float(loop.r2.min()) if loop is not None else r2_after
        worst = float(loop.max_dev.max()) if loop is not None else fit_worst
        se = [float(np.mean(u.characteristic.ogcd_stderr)) for u in self.units
              if u.characteristic.ogcd_stderr is not None]
        out: DisplayMetrics = {
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
            **self._ccm_metrics(),
            "max_step_from_last_um": self.max_step_um,
            "grouping": self.grouping, "region": self.region,
            "seconds": dict(self.seconds),
        }
        return self._corrected(out)

    def report(self) -> CentreReport | DisplayReport:
        """A JSON-serialisable report (arrays as lists), with every controller's table CRC; a
        centre-pixel run's in its own form (:meth:`_centre_report`)."""
        if self.source == CENTRE:
            return self._corrected(self._centre_report())
        crcs = self.controller_crcs()
        out: DisplayReport = {
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
                 "closed_loop_max_dev_de00": finite_or_none(u.loop_max_dev),
                 "refined_rounds": u.refined_rounds,
                 "closed_loop_r2": finite_or_none(u.loop_r2)}
                for u in self.units],
            "closed_loop": None if self.loop is None else self.loop.report(),
            "closed_loop_rounds": [
                {"round": lp.round, "max_dev_de00": float(lp.max_dev.max()),
                 "r2_min": float(lp.r2.min())} for lp in self.loop_rounds],
            "grouping": self.grouping, "region": self.region,
            "ccm": self._ccm_report(),
            "transport": self.transport,
            "lighting_notes": list(self.lighting_notes),
        }
        return self._corrected(out)

    # ------------------------------------------------------------------ one table
    def pooled(self) -> Characteristic:
        """The characteristic behind a one-unit run's table: the first simulation's points
        plus those of every closed-loop round that refined it (lengths mm, OGCD and its
        floored standard error dE00)."""
        u = self.units[0]
        c = u.characteristic
        se = c.ogcd_stderr if c.ogcd_stderr is not None else np.zeros_like(c.ogcd)
        xs, ys, ses = [c.lengths_mm], [c.ogcd], [se]
        for lp in self.loop_rounds[:u.refined_rounds]:
            xs.append(lp.lengths_mm[0])
            ys.append(lp.ogcd[0])
            ses.append(lp.ogcd_stderr[0])
        return pooled_characteristic(xs, ys, ses)

    def _centre_metrics(self, r2_goal: float, target_de00: float) -> RunMetrics:
        """Metrics of a centre-pixel run (its one table's closed loop, dE00)."""
        u, last, se = self.units[0], self.loop, self.pooled().ogcd_stderr
        return {
            "r2_before": u.r2_before,
            "r2_after_fit": u.r2_after,
            "r2_closed_loop": float(last.r2[0]) if last else None,
            "r2_goal": r2_goal,
            "r2_goal_met": bool(last and last.r2[0] >= r2_goal),
            "max_dev_de00": float(last.max_dev[0]) if last else None,
            "max_dev_goal_de00": target_de00,
            "max_dev_goal_met": bool(last and last.max_dev[0] <= target_de00),
            "rounds": len(self.loop_rounds),
            "ogcd_range_de00": u.ogcd_range,
            "mean_ogcd_stderr_de00": float(np.mean(se)) if se is not None else None,
            **self._ccm_metrics(),
            "max_step_from_last_um": self.max_step_um,
            "seconds": dict(self.seconds),
        }

    def _ccm_metrics(self) -> CcmMetrics:
        """The colour correction in the metrics: its source, the error a report prints (dE00
        mean / max; leave-one-out where known,
        :attr:`~grassd.calib.ccm.ColourCorrection.reported_de00`) and, with a correction, its
        form (a run without keeps its historic keys)."""
        c = self.ccm
        if c is None:
            return {"ccm_source": self.ccm_source, "ccm_mean_de00": None, "ccm_max_de00": None}
        mean, worst = c.reported_de00
        return {"ccm_source": self.ccm_source, "ccm_form": c.form,
                "ccm_mean_de00": finite_or_none(mean), "ccm_max_de00": finite_or_none(worst)}

    def _ccm_report(self) -> CcmReport | None:
        """The colour correction in the report: how to apply it again, its leave-one-out and
        fitting errors (dE00) and, when the form was chosen, every candidate's."""
        c = self.ccm
        if c is None:
            return None
        return {"source": self.ccm_source, "form": c.form, "method": c.method,
                "degree": c.degree, "matrix": c.matrix.tolist(),
                "mean_de00": finite_or_none(c.reported_de00[0]),
                "max_de00": finite_or_none(c.reported_de00[1]),
                "loo_mean_de00": finite_or_none(c.loo_mean_de00),
                "loo_max_de00": finite_or_none(c.loo_max_de00),
                "fit_mean_de00": finite_or_none(c.mean_de00),
                "fit_max_de00": finite_or_none(c.max_de00),
                "candidates": [asdict(k) for k in c.candidates]}

    def _corrected(self, out: _Named) -> _Named:
        """``out`` with ``display_correction`` (the measurement whose per-pixel correction the
        tables include) when there is one; a run without keeps its historic keys."""
        if self.correction is not None:
            out["display_correction"] = self.correction
        return out

    def _centre_report(self) -> CentreReport:
        """Report of a centre-pixel run: its table, pooled characteristic, per-viewpoint
        curves and closed-loop rounds (arrays as lists)."""
        w = self.pooled()
        return {
            "table_um": self.lengths_um.tolist(),
            "characteristic": {
                "lengths_mm": w.lengths_mm.tolist(),
                "ogcd_de00": w.ogcd.tolist(),
                "ogcd_stderr_de00": None if w.ogcd_stderr is None
                else w.ogcd_stderr.tolist(),
            },
            "viewpoints": [_curve_report(c) for c in self.curves],
            "closed_loop": [
                {"round": r.round, "levels": r.levels.tolist(),
                 "lengths_mm": r.lengths_mm[0].tolist(), "ogcd_de00": r.ogcd[0].tolist(),
                 "target_de00": r.target[0].tolist(), "max_dev_de00": float(r.max_dev[0]),
                 "r2": float(r.r2[0])}
                for r in self.loop_rounds
            ],
            "ccm": self._ccm_report(),
            "transport": self.transport,
            "lighting_notes": list(self.lighting_notes),
        }

    def figure(self) -> Figure:
        """A matplotlib Figure: unit characteristics, unit tables, and the worst error per
        pixel (one unit: OGCD vs level in the last closed-loop round against its target)."""
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
        if len(self.units) == 1 and self.loop is not None:
            r = self.loop
            ax3.plot(r.levels, r.ogcd[0], "ko-", ms=3, lw=0.8,
                     label=f"re-simulated, round {r.round}")
            ax3.plot(r.levels, r.target[0], "b--", lw=0.8, label="target")
            ax3.set(xlabel="8-bit level", ylabel="OGCD (dE00)", title="Linearity")
            ax3.legend(fontsize=7)
            fig.tight_layout()
            return fig
        if self.loop is not None:
            err, how = self.loop.pixel_dev(), "closed loop"
        else:
            err, how = np.array([u.max_error for u in self.units])[self.unit_of_pixel], "fit"
        im = ax3.imshow(err.reshape(self.shape), cmap="magma_r", origin="upper")
        fig.colorbar(im, ax=ax3, shrink=0.8)
        ax3.set(xlabel="column", ylabel="row", title=f"max |OGCD - linear| (dE00, {how})")
        fig.tight_layout()
        return fig


def _curve_report(c: ViewpointCurve) -> ViewpointCurveReport:
    """A centre-pixel run's curve from one viewpoint in its report (arrays as lists)."""
    out: ViewpointCurveReport = {
        "h_cm": c.viewpoint.h_cm, "d_m": c.viewpoint.d_m, "theta_deg": c.viewpoint.theta_deg,
        "weight": c.viewpoint.weight, "lengths_mm": c.lengths_mm.tolist(),
        "ogcd_de00": c.ogcd.tolist(), "ogcd_stderr_de00": c.ogcd_stderr.tolist(),
        "seconds": c.seconds}
    if c.lab is not None:
        out["lab_d50"] = c.lab.tolist()
    return out
