"""One calibration run: light -> simulated characteristics -> table -> checks -> closed loop.

Composition of :mod:`grassd.sim` and :mod:`grassd.calib` (pushing and recording are the
service's job, :mod:`grassd.daemon.runtime.service`):

1. **Lighting** from the bundle: the HDRI scaled to the ambient lux, plus a directional sun of
   ``sun_lux`` (direction from the manifest, else from the site's latitude/longitude and the
   bundle time, NREL SPA via :func:`grassd.sim.sun.sun_position`).
2. **Simulate** the centre pixel of a (up to) 3 x 3 patch of the display (so neighbours shade
   it as on the real display) from every configured viewpoint at the configured lengths (mm),
   with ``replicates`` independent Monte Carlo estimates (common random numbers across lengths).
3. **Exposure**: renders are in nits; they are divided by the radiance of a perfect diffuse white
   lying flat at the display (horizontal irradiance / pi), so Y = 1 is reference white as CIELAB
   expects and an 18 % grey card reads 0.18 (the convention of ``grassd simulate``:
   :func:`grassd.daemon.calibration.simulation.simulate_curve` does the rendering and OGCD here
   too).
4. **Colour correction** (paper, section 5.2): with a colour-checker RAW in the bundle, the
   virtual patches are the chart's reference reflectances lit by the same horizontal
   irradiance (a flat chart at the display), the real ones the developed RAW's patches; both are
   exposure-normalised on the grey patch and a 3x3 matrix is fitted (real ~= M . virtual).
   Without a RAW the last matrix is reused (``previous_ccm``), else none is applied.
5. **Weighted characteristic**: OGCD per viewpoint (CIEDE2000 from the shortest length, with
   correlation-aware errors from the replicates), averaged with the viewpoint weights.
6. **Shape check** (as OpenVPCal refuses a calibration from a bad measurement): refuse a
   characteristic with too many flat steps (|step| <= max(2 sigma, 1 % of the range)) or any
   wild step (a drop of more than 3 sigma + 10 % of the range).
7. **Table**: monotone fit and 256-entry inversion (:func:`grassd.calib.build_length_table`).
8. **Sanity**: 256 finite, integer, non-decreasing entries within 0..green_max; no entry moves
   more than ``max_jump_mm`` from the last table unless forced.
9. **Closed loop** (as ArgyllCMS dispcal re-measures and corrects until a dE threshold):
   re-simulate at the table's lengths for ``check_levels`` levels, compare OGCD with the target
   ``v / 255 x OGCD(255)``; while the largest deviation exceeds ``target_de00`` and fewer than
   ``max_rounds`` rounds ran, add the new points to the characteristic (fresh seed, so they
   average with the old ones), refit and rebuild. R^2 of OGCD vs level is reported per round.
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

from grassd.calib.ccm import ColourCorrection, fit_ccm
from grassd.calib.characteristic import Characteristic, fit_characteristic, floor_stderr
from grassd.calib.charts import get_chart
from grassd.calib.colour_spaces import luminance
from grassd.calib.exposure import normalise_exposure
from grassd.calib.length_table import LEVELS, LengthTable, build_length_table, r_squared
from grassd.calib.raw import develop_raw
from grassd.daemon.calibration.simulation import simulate_curve, white_radiance
from grassd.daemon.config.settings import Config, ViewpointConfig
from grassd.daemon.errors import CalibrationRejected, RunInterrupted
from grassd.sim.light_input import LightInput

if TYPE_CHECKING:
    from grassd.daemon.calibration.calibrate_display import DisplayCalibrationResult
    from grassd.daemon.store.ingest import CheckerPhoto

log = logging.getLogger(__name__)

Progress = Callable[[str], None]


@dataclass(frozen=True)
class ViewpointCurve:
    """OGCD (dE00) vs length (mm) simulated from one viewpoint."""

    viewpoint: ViewpointConfig
    lengths_mm: NDArray[np.float64]
    ogcd: NDArray[np.float64]
    ogcd_stderr: NDArray[np.float64]
    seconds: float


@dataclass(frozen=True)
class LoopRound:
    """One closed-loop check: OGCD measured at the table's lengths for the check levels."""

    round: int
    levels: NDArray[np.int64]
    lengths_mm: NDArray[np.float64]
    ogcd: NDArray[np.float64]
    target: NDArray[np.float64]
    max_dev_de00: float
    r2: float


@dataclass
class CalibrationResult:
    """Everything a run produced. ``lengths_um``: the 256-entry table (uint16 micrometres)."""

    table: LengthTable
    curves: list[ViewpointCurve]
    weighted: Characteristic
    rounds: list[LoopRound]
    ccm: ColourCorrection | None
    ccm_source: str
    lighting_notes: tuple[str, ...]
    seconds: dict[str, float] = field(default_factory=dict)
    max_step_um: int | None = None

    @property
    def lengths_um(self) -> NDArray[np.uint16]:
        """The final table (uint16 micrometres, one entry per 8-bit level)."""
        return self.table.lengths_um

    def metrics(self, r2_goal: float = 0.999, target_de00: float = 0.5) -> dict[str, Any]:
        """Summary numbers for history and status (dE00 = CIEDE2000 units)."""
        last = self.rounds[-1] if self.rounds else None
        return {
            "r2_before": self.table.r2_before,
            "r2_after_fit": self.table.r2_after,
            "r2_closed_loop": last.r2 if last else None,
            "r2_goal": r2_goal,
            "r2_goal_met": bool(last and last.r2 >= r2_goal),
            "max_dev_de00": last.max_dev_de00 if last else None,
            "max_dev_goal_de00": target_de00,
            "max_dev_goal_met": bool(last and last.max_dev_de00 <= target_de00),
            "rounds": len(self.rounds),
            "ogcd_range_de00": self.table.ogcd_range,
            "mean_ogcd_stderr_de00": float(np.mean(self.weighted.ogcd_stderr))
            if self.weighted.ogcd_stderr is not None else None,
            "ccm_source": self.ccm_source,
            "ccm_mean_de00": _finite_or_none(self.ccm.mean_de00) if self.ccm else None,
            "ccm_max_de00": _finite_or_none(self.ccm.max_de00) if self.ccm else None,
            "max_step_from_last_um": self.max_step_um,
            "seconds": dict(self.seconds),
        }

    def report(self) -> dict[str, Any]:
        """A JSON-serialisable report of the run (arrays as lists)."""
        return {
            "table_um": self.lengths_um.tolist(),
            "characteristic": {
                "lengths_mm": self.weighted.lengths_mm.tolist(),
                "ogcd_de00": self.weighted.ogcd.tolist(),
                "ogcd_stderr_de00": None if self.weighted.ogcd_stderr is None
                else self.weighted.ogcd_stderr.tolist(),
            },
            "viewpoints": [
                {"h_cm": c.viewpoint.h_cm, "d_m": c.viewpoint.d_m,
                 "theta_deg": c.viewpoint.theta_deg, "weight": c.viewpoint.weight,
                 "lengths_mm": c.lengths_mm.tolist(), "ogcd_de00": c.ogcd.tolist(),
                 "ogcd_stderr_de00": c.ogcd_stderr.tolist(), "seconds": c.seconds}
                for c in self.curves
            ],
            "closed_loop": [
                {"round": r.round, "levels": r.levels.tolist(), "lengths_mm": r.lengths_mm.tolist(),
                 "ogcd_de00": r.ogcd.tolist(), "target_de00": r.target.tolist(),
                 "max_dev_de00": r.max_dev_de00, "r2": r.r2}
                for r in self.rounds
            ],
            "ccm": None if self.ccm is None else {
                "source": self.ccm_source, "method": self.ccm.method,
                "matrix": self.ccm.matrix.tolist(),
                "mean_de00": _finite_or_none(self.ccm.mean_de00),
                "max_de00": _finite_or_none(self.ccm.max_de00),
            },
            "lighting_notes": list(self.lighting_notes),
        }

    def figure(self) -> Any:
        """A matplotlib Figure: characteristics, the table, and the closed-loop check."""
        from matplotlib.figure import Figure  # only when plotting

        fig = Figure(figsize=(12, 4), dpi=100)
        ax1, ax2, ax3 = fig.subplots(1, 3)
        for c in self.curves:
            v = c.viewpoint
            ax1.errorbar(c.lengths_mm, c.ogcd, yerr=c.ogcd_stderr, fmt=".-", lw=0.8,
                         label=f"({v.h_cm:g}, {v.d_m:g}, {v.theta_deg:g}) w={v.weight:g}")
        w = self.weighted
        ax1.plot(w.lengths_mm, w.ogcd, "k.", label="weighted + loop points")
        ax1.set(xlabel="green length (mm)", ylabel="OGCD (dE00)", title="Characteristic")
        ax1.legend(fontsize=7)
        levels = np.arange(LEVELS)
        ax2.plot(levels, self.lengths_um / 1000.0, "g-")
        ax2.set(xlabel="8-bit level", ylabel="length (mm)", title="Length table")
        ax3.plot(levels, self.table.uncalibrated_ogcd, "r-", lw=0.8, label="linear lengths (fit)")
        ax3.plot(levels, self.table.achieved_ogcd, "g-", lw=0.8, label="table (fit)")
        if self.rounds:
            r = self.rounds[-1]
            ax3.plot(r.levels, r.ogcd, "ko", ms=3, label=f"re-simulated, round {r.round}")
            ax3.plot(r.levels, r.target, "b--", lw=0.8, label="target")
        ax3.set(xlabel="8-bit level", ylabel="OGCD (dE00)", title="Linearity")
        ax3.legend(fontsize=7)
        fig.tight_layout()
        return fig


def _finite_or_none(x: float | None) -> float | None:
    """``x`` as a float, or None when it is missing or not finite (reports are strict JSON: a
    reused matrix has no residuals, so its mean/max dE00 are NaN)."""
    if x is None or not np.isfinite(x):
        return None
    return float(x)


# --------------------------------------------------------------------------- checks


def check_shape(lengths_mm: NDArray, ogcd: NDArray, stderr: NDArray | None,
                max_flat_fraction: float) -> dict[str, float]:
    """Refuse a characteristic with too many flat or any wild steps (see module docstring).

    Returns the step statistics; raises :class:`CalibrationRejected`.
    """
    order = np.argsort(lengths_mm, kind="stable")
    y = np.asarray(ogcd, float)[order]
    se = np.zeros_like(y) if stderr is None else np.asarray(stderr, float)[order]
    steps = np.diff(y)
    noise = np.sqrt(se[:-1] ** 2 + se[1:] ** 2)
    rng = float(y.max() - y.min())
    flat = np.abs(steps) <= np.maximum(2.0 * noise, 0.01 * rng)
    wild = steps < -(3.0 * noise + 0.10 * rng)
    flat_fraction = float(flat.mean()) if steps.size else 1.0
    stats = {"flat_fraction": flat_fraction, "wild_steps": int(wild.sum()), "range": rng}
    if wild.any():
        i = int(np.argmax(wild))
        x = np.asarray(lengths_mm, float)[order]
        raise CalibrationRejected(
            f"characteristic has a wild step: OGCD drops by {-steps[i]:.2f} dE00 between "
            f"{x[i]:g} and {x[i + 1]:g} mm (noise {noise[i]:.2f}); check the light inputs")
    if flat_fraction > max_flat_fraction:
        raise CalibrationRejected(
            f"characteristic is flat over {flat_fraction:.0%} of its steps (limit "
            f"{max_flat_fraction:.0%}): the light cannot show the grass; no table built")
    return stats


def check_levels(n: int) -> NDArray[np.int64]:
    """The 8-bit levels the closed loop re-simulates: ``n`` evenly spaced over 0..255, rounded,
    duplicates dropped (level 0 is the reference length, 255 the top of the range).

    >>> check_levels(5).tolist()
    [0, 64, 128, 191, 255]
    """
    return np.unique(np.rint(np.linspace(0, LEVELS - 1, n)).astype(np.int64))


def pooled_characteristic(xs: Sequence[NDArray], ys: Sequence[NDArray],
                          ses: Sequence[NDArray]) -> Characteristic:
    """One characteristic of every point simulated for a table so far (the first simulation's
    lengths [mm], OGCD and standard errors [dE00], then each closed-loop round's), the errors
    floored (:func:`grassd.calib.characteristic.floor_stderr`) so that every point keeps a
    finite fit weight: what a closed loop refits its table to."""
    return Characteristic(np.concatenate(xs), np.concatenate(ys),
                          floor_stderr(np.concatenate(ses)))


def check_table(lengths_um: NDArray, green_max_mm: float, previous_um: NDArray | None,
                max_jump_mm: float, force: bool, what: str = "table") -> int | None:
    """Sanity checks of a table (micrometres); returns the largest step from ``previous_um``.

    ``lengths_um``: one table (256,) or per-pixel tables (n, 256), every row checked;
    ``previous_um`` must broadcast against it (a (256,) table against (n, 256) compares every
    row). ``what`` names the table in messages (e.g. a controller). Raises
    :class:`CalibrationRejected` naming the first problem found.
    """
    t = np.asarray(lengths_um)
    if t.ndim not in (1, 2) or t.shape[-1] != LEVELS or t.size == 0:
        raise CalibrationRejected(f"{what} has shape {t.shape}, expected ({LEVELS},) or "
                                  f"(n_pixels, {LEVELS})")
    if not np.all(np.isfinite(t.astype(float))):
        raise CalibrationRejected(f"{what} holds non-finite entries")
    if np.any(np.diff(t.astype(np.int64), axis=-1) < 0):
        raise CalibrationRejected(f"{what} is not monotone (non-decreasing)")
    top = round(green_max_mm * 1000)
    if int(t.min()) < 0 or int(t.max()) > top:
        raise CalibrationRejected(f"{what} leaves the range 0..{top} um")
    if previous_um is None:
        return None
    jump = int(np.abs(t.astype(np.int64) - np.asarray(previous_um, np.int64)).max())
    if jump > max_jump_mm * 1000 and not force:
        raise CalibrationRejected(
            f"{what} differs from the active one by up to {jump / 1000:.2f} mm (limit "
            f"{max_jump_mm:g} mm): a wild jump; run `grassd calibrate --now --force` to accept it")
    return jump


# --------------------------------------------------------------------------- the run


def init_backend(cfg: Config) -> str:
    """Initialise Taichi once for this process (CPU, offline cache in ``cfg.cache_dir``)."""
    from grassd.sim import backend

    return backend.init("cpu", cache_dir=cfg.cache_dir / "taichi")


class Calibrator:
    """Runs calibrations for one configuration (renderer and Taichi shared per process)."""

    def __init__(self, cfg: Config) -> None:
        self.cfg = cfg

    # ------------------------------------------------------------------ pieces
    def lighting(self, light: LightInput) -> Any:
        """Build the :class:`grassd.sim.lighting.Lighting` of ``light`` (lux-scaled HDRI + sun),
        the HDRI oriented by ``[light] hdri_flip`` / ``hdri_rotation_deg``. A light whose sun is
        clipped in the HDRI (``sun_from_hdri``, flagged by a capture station) and that has no sun
        direction gets its sun restored from the map; otherwise (or when that fails) the sun
        of a sun lux reading is placed from site and time."""
        from grassd.sim.errors import LightingError
        from grassd.sim.sun import sun_position

        light = replace(light, flip=self.cfg.light.hdri_flip,
                        rotation_deg=self.cfg.light.hdri_rotation_deg)
        notes: list[str] = []
        if light.sun_from_hdri and light.sun_azimuth_deg is None:
            try:
                return light.lighting()
            except LightingError as exc:  # the clipped sun is not found as a compact sun
                notes.append(f"clipped sun not restored from the HDRI ({exc}); sun from "
                             "site and time")
        az, el = light.sun_azimuth_deg, light.sun_elevation_deg
        sun = light.sun_lux
        if sun is not None and sun > 0 and az is None:
            az, el = sun_position(self.cfg.site.latitude, self.cfg.site.longitude,
                                  light.timestamp)
            notes.append(f"sun direction from site and time: azimuth {az:.1f}, "
                         f"elevation {el:.1f} deg")
            if el <= 0:
                notes.append("sun below the horizon at that time: sun lux ignored")
                sun, az, el = None, None, None
        if sun is not None and sun == 0:
            sun, az, el = None, None, None
        lighting = replace(light, sun_lux=sun, sun_azimuth_deg=az, sun_elevation_deg=el,
                           sun_from_hdri=False).lighting()
        object.__setattr__(lighting, "notes", tuple(lighting.notes) + tuple(notes))
        return lighting

    def display(self) -> tuple[Any, int]:
        """(DisplaySpec of an up-to-3x3 patch of the display, with the ``[tables] layout`` of
        :func:`grassd.daemon.calibration.display_model.display_spec_for_config`; index of its centre
        pixel)."""
        from grassd.daemon.calibration.display_model import display_spec_for_config

        d = self.cfg.display
        rows, cols = min(d.rows, 3), min(d.cols, 3)
        spec = replace(display_spec_for_config(self.cfg), rows=rows, cols=cols)
        return spec, (rows // 2) * cols + cols // 2

    def white_radiance(self, lighting: Any) -> NDArray[np.float64]:
        """Rec.709 radiance (nits) of a perfect diffuse white lying flat at the display (the
        white reference shared with ``grassd simulate``,
        :mod:`grassd.daemon.calibration.simulation`)."""
        return white_radiance(lighting)

    def fit_checker_ccm(self, checker: CheckerPhoto) -> ColourCorrection:
        """3x3 CCM from the bundle's checker RAW (see module docstring, step 4)."""
        chart = get_chart(checker.chart)
        real = develop_raw(checker.raw).checker_patches(checker.corners)
        # The analytic virtual checker in the renders' normalisation (radiance divided by the
        # white card's, channel by channel): each patch reads its albedo, in ProPhoto linear.
        virtual = chart.prophoto()
        grey = chart.grey_index()
        # The photo is scaled so its grey patch reads that patch's reference luminance, so M
        # maps white-card-normalised renders straight onto the photo's scale.
        r = normalise_exposure(real, real[grey], space="prophoto",
                               target_y=float(luminance(virtual[grey], "prophoto")))
        return fit_ccm(virtual, r, "3x3")

    def simulate(self, lighting: Any, lengths_mm: NDArray, seed: int,
                 ccm: ColourCorrection | None, stop: threading.Event | None,
                 progress: Progress | None) -> list[ViewpointCurve]:
        """OGCD vs ``lengths_mm`` (first entry = reference) from every viewpoint."""
        from grassd.sim.renderer import Renderer  # imports Taichi
        from grassd.sim.scene import RenderSettings, Viewpoint

        display, centre = self.display()
        settings = RenderSettings(samples=self.cfg.simulation.samples,
                                  replicates=self.cfg.calibration.replicates, seed=seed)
        curves = []
        for i, vp in enumerate(self.cfg.viewpoints):
            if stop is not None and stop.is_set():
                raise RunInterrupted("calibration stopped (daemon shutting down)")
            if progress:
                progress(f"simulating viewpoint {i + 1}/{len(self.cfg.viewpoints)} "
                         f"({vp.h_cm:g}, {vp.d_m:g}, {vp.theta_deg:g})")
            t0 = time.perf_counter()
            c = simulate_curve(Renderer.shared(), display, lighting,
                               Viewpoint(vp.h_cm, vp.d_m, vp.theta_deg),
                               np.asarray(lengths_mm, float), settings, ccm=ccm,
                               pixel_index=centre, layouts=self.cfg.simulation.layouts)
            curves.append(ViewpointCurve(vp, np.asarray(lengths_mm, float), c.ogcd,
                                         c.ogcd_stderr, time.perf_counter() - t0))
        return curves

    @staticmethod
    def weighted(curves: list[ViewpointCurve]) -> tuple[NDArray, NDArray]:
        """Viewpoint-weighted mean OGCD and its standard error (independent viewpoints)."""
        w = np.array([c.viewpoint.weight for c in curves], float)
        w = w / w.sum()
        y = np.stack([c.ogcd for c in curves])
        se = np.stack([c.ogcd_stderr for c in curves])
        return w @ y, np.sqrt((w**2) @ (se**2))

    # ------------------------------------------------------------------ run
    @property
    def per_display(self) -> bool:
        """True when the config asks for more than the one global table from [[viewpoints]]:
        ``[tables] granularity`` "controller"/"pixel", or an ``[audience]`` region. Such runs
        go through :func:`grassd.daemon.calibration.calibrate_display.calibrate_display`."""
        return self.cfg.tables.granularity != "global" or self.cfg.audience is not None

    def light_and_ccm(self, light: LightInput, checker: CheckerPhoto | None,
                      previous_ccm: NDArray | None,
                      progress: Progress | None) -> tuple[Any, ColourCorrection | None, str]:
        """(Lighting, colour correction or None, its source "bundle" (fitted to ``checker``) /
        "previous" / "none")."""
        if progress:
            progress("building the lighting")
        lighting = self.lighting(light)
        ccm: ColourCorrection | None = None
        ccm_source = "none"
        if checker is not None:
            if progress:
                progress("fitting the colour-correction matrix from the checker RAW")
            ccm = self.fit_checker_ccm(checker)
            ccm_source = "bundle"
        elif previous_ccm is not None:
            m = np.asarray(previous_ccm, float)
            ccm = ColourCorrection("3x3", m, 1, np.zeros(0), float("nan"), float("nan"))
            ccm_source = "previous"
        return lighting, ccm, ccm_source

    def run(self, light: LightInput, *, checker: CheckerPhoto | None = None,
            previous_um: NDArray | None = None,
            previous_ccm: NDArray | None = None, force: bool = False,
            stop: threading.Event | None = None,
            progress: Progress | None = None,
            previous_tables: Mapping[str, NDArray] | None = None
            ) -> CalibrationResult | DisplayCalibrationResult:
        """Calibrate for ``light`` (colour-corrected with the bundle's ``checker`` photo if
        given); raises CalibError/SimError/CalibrationRejected on bad input
        and :class:`RunInterrupted` when ``stop`` is set.

        Returns a :class:`CalibrationResult` (one global table from [[viewpoints]]) or, when
        :attr:`per_display`, a
        :class:`grassd.daemon.calibration.calibrate_display.DisplayCalibrationResult` (a table per
        controller / per pixel, or from the audience region; ``previous_tables`` are the last run's
        tables by controller name, for the jump check)."""
        if self.per_display:
            from grassd.daemon.calibration.calibrate_display import calibrate_display

            return calibrate_display(self, light, checker=checker, previous_um=previous_um,
                                     previous_tables=previous_tables,
                                     previous_ccm=previous_ccm, force=force, stop=stop,
                                     progress=progress)
        cal = self.cfg.calibration
        t_start = time.perf_counter()
        lighting, ccm, ccm_source = self.light_and_ccm(light, checker, previous_ccm, progress)

        lengths = np.asarray(self.cfg.simulation.lengths_mm, float)
        seed = self.cfg.simulation.seed
        curves = self.simulate(lighting, lengths, seed, ccm, stop, progress)
        t_sim = time.perf_counter() - t_start
        y, se = self.weighted(curves)
        check_shape(lengths, y, se, cal.max_flat_fraction)
        all_x, all_y, all_se = [lengths], [y], [se]
        weighted = pooled_characteristic(all_x, all_y, all_se)
        table = build_length_table(fit_characteristic(weighted))
        green_max = self.cfg.display.green_max_mm

        rounds: list[LoopRound] = []
        levels = check_levels(cal.check_levels)
        for k in range(1, cal.max_rounds + 1):
            check_table(table.lengths_um, green_max, None, cal.max_jump_mm, force)
            if progress:
                progress(f"closed loop round {k}: re-simulating {levels.size} levels")
            lx = table.lengths_um[levels].astype(float) / 1000.0
            loop_progress = (None if progress is None else
                             lambda text, k=k: progress(f"closed loop round {k}: {text}"))
            loop_curves = self.simulate(lighting, lx, seed + 1000 * k, ccm, stop, loop_progress)
            ly, lse = self.weighted(loop_curves)
            target = levels / (LEVELS - 1) * ly[-1]
            dev = float(np.abs(ly - target).max())
            r2 = r_squared(levels, ly)
            rounds.append(LoopRound(k, levels, lx, ly, target, dev, r2))
            log.info("closed loop round %d: max deviation %.3f dE00, R^2 %.5f", k, dev, r2)
            if dev <= cal.target_de00 or k == cal.max_rounds:
                break
            all_x.append(lx)
            all_y.append(ly)
            all_se.append(lse)
            weighted = pooled_characteristic(all_x, all_y, all_se)
            table = build_length_table(fit_characteristic(weighted))

        max_step = check_table(table.lengths_um, green_max, previous_um, cal.max_jump_mm, force)
        notes = tuple(getattr(lighting, "notes", ()))
        total = time.perf_counter() - t_start
        return CalibrationResult(table=table, curves=curves, weighted=weighted, rounds=rounds,
                                 ccm=ccm, ccm_source=ccm_source, lighting_notes=notes,
                                 seconds={"simulate": t_sim, "total": total},
                                 max_step_um=max_step)
