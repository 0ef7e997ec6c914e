"""One calibration run: light -> simulated characteristics -> tables -> checks -> closed loop.

Composition of :mod:`grassd.sim` and :mod:`grassd.calib` (pushing and recording are the
service's job, :mod:`grassd.daemon.core.runtime.service`). Every run, whatever ``[tables]
granularity`` and ``[audience]`` ask, goes through :meth:`Calibrator.run`:

1. **Lighting** from the bundle: the HDRI scaled to the ambient lux, plus a directional sun of
   ``sun_lux`` (direction from the manifest, else from the site's latitude/longitude and the
   bundle time, NREL SPA via :func:`grassd.sim.sun.sun_position`).
2. **Colour correction** (paper, section 5.2): with a colour-checker RAW in the bundle, the
   virtual patches are the chart's reference reflectances lit by the same horizontal
   irradiance (a flat chart at the display), the real ones the developed RAW's patches; both are
   exposure-normalised on the grey patch and a correction is fitted (real ~= M . virtual):
   the paper's 3x3, or Finlayson's root-polynomial, chosen by the leave-one-out error the
   report prints (``[calibration] ccm``). A photo whose patches clip is refused. Without a
   RAW the last correction is reused (``previous_ccm``), else none is applied.
3. **Units** from the run's source (:mod:`grassd.daemon.core.calibration.units`): the centre
   pixel of a patch from every viewpoint (one table), the whole display from every viewpoint,
   or an audience region; renders in nits are divided by the radiance of a perfect diffuse white
   lying flat at the display (:func:`grassd.daemon.core.calibration.simulation.simulate_curve`),
   OGCD per viewer with correlation-aware errors from ``replicates``, averaged with the weights.
4. **Shape check** of every unit's characteristic and **table checks** of every table
   (:mod:`grassd.daemon.core.calibration.checks`).
5. **Closed loop** (as ArgyllCMS dispcal re-measures and corrects until a dE threshold), up to
   ``max_rounds`` rounds (:func:`closed_loop_check`): every pixel group's representative (a
   group whose members two tables drive is checked once per table,
   :meth:`~grassd.daemon.core.calibration.units.Viewers.split_by_table`) is re-simulated by every
   viewer at its own table's lengths for ``check_levels`` levels (a fresh seed per round) and
   its weighted OGCD is compared with the linear target ``v / 255 x OGCD(255)``; a unit whose
   pixels deviate by more than ``target_de00`` gets the round's points added to its fit and a
   new table (:func:`refine_unit`), which passes the table checks again, and the next round
   re-checks. ``max_dev_de00`` and ``r2_closed_loop`` are the worst group's in the last round.
   Tables from ``[audience]`` are checked in one round and not refined: a region table is not
   the inverse of one characteristic.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Protocol

import numpy as np
from numpy.typing import NDArray

from grassd.calib.ccm import CCM_FORMS, ColourCorrection, select_ccm
from grassd.calib.characteristic import Characteristic, fit_characteristic
from grassd.calib.charts import get_chart
from grassd.calib.checker_photo import checker_photo_patches
from grassd.calib.colour_spaces import luminance
from grassd.calib.exposure import normalise_exposure
from grassd.calib.length_table import LEVELS, build_length_table, r_squared
from grassd.daemon.core.calibration.checks import (
    check_levels,
    check_shape,
    check_table,
    pooled_characteristic,
)
from grassd.daemon.core.calibration.correction import (
    SAVED,
    DisplayCorrection,
    Saved,
    with_correction,
)
from grassd.daemon.core.calibration.display_model import (
    capacity_for,
    display_spec_for_config,
    table_deviation,
)
from grassd.daemon.core.calibration.result import (
    CENTRE,
    CalibrationResult,
    LoopCheck,
    UnitTable,
    ViewpointCurve,
)
from grassd.daemon.core.calibration.simulation import simulate_curve, white_radiance
from grassd.daemon.core.calibration.transport import SpectralTransport
from grassd.daemon.core.calibration.units import (
    Viewers,
    audience_units,
    centre_units,
    controller_tables_of,
    r2_pair,
    viewpoint_units,
)
from grassd.daemon.core.config.settings import CalibrationConfig, Config, ViewpointConfig
from grassd.daemon.core.errors import CalibrationRejected, RunInterrupted
from grassd.sim.light_input import LightInput

if TYPE_CHECKING:
    from grassd.daemon.core.store.manifest import CheckerPhoto
    from grassd.sim.lighting import Lighting
    from grassd.sim.renderer import Renderer
    from grassd.sim.scene import DisplaySpec, RenderSettings, Viewpoint

log = logging.getLogger(__name__)

Progress = Callable[[str], None]

__all__ = ["Calibrator", "CalibrationResult", "LightInput", "closed_loop", "closed_loop_check",
           "init_backend", "refine_unit"]


def init_backend(cfg: Config) -> str:
    """Initialise Taichi once for this process (CPU, offline cache in ``cfg.cache_dir``)."""
    from grassd.sim import backend

    return backend.init("cpu", cache_dir=cfg.cache_dir / "taichi")


class Calibrates(Protocol):
    """What runs a configuration's calibrations: a :class:`Calibrator` here, or the compute
    feature's ``RemoteCalibrator`` on a Dask cluster; both run as :meth:`Calibrator.run`."""

    def run(self, light: LightInput, *, checker: CheckerPhoto | None = None,
            previous_um: NDArray | None = None,
            previous_ccm: ColourCorrection | None = None, force: bool = False,
            stop: threading.Event | None = None,
            progress: Progress | None = None,
            previous_tables: Mapping[str, NDArray] | None = None,
            correction: DisplayCorrection | Saved | None = SAVED) -> CalibrationResult:
        """Calibrate for ``light`` (:meth:`Calibrator.run`)."""
        ...


class Calibrator:
    """Runs calibrations for one configuration (renderer and Taichi shared per process)."""

    def __init__(self, cfg: Config) -> None:
        self.cfg = cfg

    # ------------------------------------------------------------------ pieces
    def lighting(self, light: LightInput) -> Lighting:
        """Build the :class:`grassd.sim.lighting.Lighting` of ``light`` (lux-scaled HDRI + sun),
        the HDRI oriented by ``[light] hdri_flip`` / ``hdri_rotation_deg``. A light whose sun is
        clipped in the HDRI (``sun_from_hdri``, flagged by a capture station) and that has no sun
        direction gets its sun restored from the map; otherwise (or when that fails) the sun
        of a sun lux reading is placed from site and time. The map is read at most the
        renderer's size (:data:`grassd.sim.hdri.RENDERER_TEXELS`), a bigger one refused from
        its header."""
        from grassd.sim.errors import LightingError
        from grassd.sim.hdri import RENDERER_TEXELS
        from grassd.sim.sun import sun_position

        light = replace(light, flip=self.cfg.light.hdri_flip,
                        rotation_deg=self.cfg.light.hdri_rotation_deg)
        notes: list[str] = []
        if light.sun_from_hdri and light.sun_azimuth_deg is None:
            try:
                return light.lighting(max_texels=RENDERER_TEXELS)
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
                           sun_from_hdri=False).lighting(max_texels=RENDERER_TEXELS)
        object.__setattr__(lighting, "notes", tuple(lighting.notes) + tuple(notes))
        return lighting

    def display(self) -> tuple[DisplaySpec, int]:
        """(DisplaySpec of an up-to-3x3 patch of the display, with the ``[tables] layout`` of
        :func:`grassd.daemon.core.calibration.display_model.display_spec_for_config`; index of its
        centre pixel)."""
        from grassd.daemon.core.calibration.display_model import display_spec_for_config

        d = self.cfg.display
        rows, cols = min(d.rows, 3), min(d.cols, 3)
        spec = replace(display_spec_for_config(self.cfg), rows=rows, cols=cols)
        return spec, (rows // 2) * cols + cols // 2

    def transport(self, display: DisplaySpec, lighting: Lighting) -> SpectralTransport | None:
        """The spectral transport of ``display``'s pixel under ``lighting`` with ``[simulation]
        transport = "spectral"``, else None (Rec.709 transport)."""
        sim = self.cfg.simulation
        if sim.transport != "spectral":
            return None
        return SpectralTransport.of(display, lighting, sim.spectral_share)

    def white_radiance(self, lighting: Lighting) -> NDArray[np.float64]:
        """Rec.709 radiance (nits) of a perfect diffuse white lying flat at the display (the
        white reference shared with ``grassd simulate``,
        :mod:`grassd.daemon.core.calibration.simulation`)."""
        return white_radiance(lighting)

    def fit_checker_ccm(self, checker: CheckerPhoto) -> ColourCorrection:
        """The colour correction from the bundle's checker RAW (see module docstring, step 4):
        the ``[calibration] ccm`` form, or with "auto" the form of lowest leave-one-out mean
        CIEDE2000 (:func:`grassd.calib.ccm.select_ccm`).

        Raises:
            ClippedCheckerError: a patch of the photo clips (the message names it and the fix).
        """
        chart = get_chart(checker.chart)
        real = checker_photo_patches(Path(checker.raw), checker.corners, chart)
        # The analytic virtual checker in the renders' normalisation (radiance divided by the
        # white card's, channel by channel): each patch reads its albedo, in ProPhoto linear.
        virtual = chart.prophoto()
        grey = chart.grey_index()
        # The photo is scaled so its grey patch reads that patch's reference luminance, so the
        # correction maps white-card-normalised renders straight onto the photo's scale.
        r = normalise_exposure(real, real[grey], space="prophoto",
                               target_y=float(luminance(virtual[grey], "prophoto")))
        form = self.cfg.calibration.ccm
        return select_ccm(virtual, r, tuple(CCM_FORMS) if form == "auto" else (form,))

    def simulate(self, lighting: Lighting, lengths_mm: NDArray, seed: int,
                 ccm: ColourCorrection | None, spectral: SpectralTransport | None,
                 stop: threading.Event | None, progress: Progress | None
                 ) -> list[ViewpointCurve]:
        """OGCD vs ``lengths_mm`` (first entry = reference) from every viewpoint, with
        ``spectral`` transport where given (:meth:`transport`)."""
        from grassd.sim.renderer import Renderer  # imports Taichi
        from grassd.sim.scene import RenderSettings

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
            c = simulate_curve(Renderer.shared(), display, lighting, self.viewpoint(vp),
                               np.asarray(lengths_mm, float), settings, ccm=ccm,
                               pixel_index=centre, layouts=self.cfg.simulation.layouts,
                               spectral=spectral)
            curves.append(ViewpointCurve(vp, np.asarray(lengths_mm, float), c.ogcd,
                                         c.ogcd_stderr, time.perf_counter() - t0,
                                         step_stderr=c.step_stderr, lab=c.lab))
        return curves

    @staticmethod
    def viewpoint(vp: ViewpointConfig) -> Viewpoint:
        """The :class:`grassd.sim.scene.Viewpoint` of a [[viewpoints]] entry (cm, m, deg)."""
        from grassd.sim.scene import Viewpoint

        return Viewpoint(vp.h_cm, vp.d_m, vp.theta_deg)

    @property
    def source(self) -> str:
        """Who the run's tables are for: :data:`~grassd.daemon.core.calibration.result.CENTRE` (one
        table from [[viewpoints]]: ``[tables] granularity = "global"`` without
        ``[audience]``), "viewpoints" (a table per controller or per pixel group) or
        "audience"."""
        if self.cfg.audience is not None:
            return "audience"
        return CENTRE if self.cfg.tables.granularity == "global" else "viewpoints"

    @staticmethod
    def weighted(curves: list[ViewpointCurve]) -> tuple[NDArray, NDArray, NDArray | None]:
        """Viewpoint-weighted mean OGCD [dE00], its standard error and that of its steps (None
        when a curve has none), the viewpoints taken as independent."""
        w = np.array([c.viewpoint.weight for c in curves], float)
        w = w / w.sum()
        y = np.stack([c.ogcd for c in curves])
        se = np.stack([c.ogcd_stderr for c in curves])
        steps = None
        if all(c.step_stderr is not None for c in curves):
            steps = np.sqrt((w**2) @ np.stack([c.step_stderr for c in curves]) ** 2)
        return w @ y, np.sqrt((w**2) @ (se**2)), steps

    def light_and_ccm(self, light: LightInput, checker: CheckerPhoto | None,
                      previous_ccm: ColourCorrection | None,
                      progress: Progress | None
                      ) -> tuple[Lighting, ColourCorrection | None, str]:
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
            ccm = previous_ccm
            ccm_source = "previous"
        return lighting, ccm, ccm_source

    def run(self, light: LightInput, *, checker: CheckerPhoto | None = None,
            previous_um: NDArray | None = None,
            previous_ccm: ColourCorrection | None = None, force: bool = False,
            stop: threading.Event | None = None,
            progress: Progress | None = None,
            previous_tables: Mapping[str, NDArray] | None = None,
            correction: DisplayCorrection | Saved | None = SAVED) -> CalibrationResult:
        """Calibrate for ``light`` (colour-corrected with the bundle's ``checker`` photo if
        given; see the module docstring). ``previous_um`` is the active display-wide table and
        ``previous_tables`` the last run's tables by controller name, for the jump check.
        ``correction``: the display's per-pixel correction the tables include
        (:class:`~grassd.daemon.core.calibration.correction.DisplayCorrection`): by default the one
        the state directory holds (none before the display was measured), None for none.

        Raises CalibError/SimError/:class:`CalibrationRejected` on bad input and
        :class:`RunInterrupted` when ``stop`` is set (checked per trace)."""
        from grassd.sim.renderer import Renderer
        from grassd.sim.scene import RenderSettings

        cfg, cc, source = self.cfg, self.cfg.calibration, self.source
        t_start = time.perf_counter()
        lighting, ccm, ccm_source = self.light_and_ccm(light, checker, previous_ccm, progress)
        settings = RenderSettings(samples=cfg.simulation.samples,
                                  replicates=cc.replicates, seed=cfg.simulation.seed)
        lengths = np.asarray(cfg.simulation.lengths_mm, float)

        def stepper(what: str) -> Callable[[int, int], None]:
            def step(done: int, total: int) -> None:
                if stop is not None and stop.is_set():
                    raise RunInterrupted("calibration stopped (daemon shutting down)")
                if progress:
                    progress(f"{what} ({source}, {cfg.tables.granularity} tables): "
                             f"trace {done}/{total}")
            return step

        if source == CENTRE:
            display, centre = self.display()
            renderer = Renderer.shared()
            spectral = self.transport(display, lighting)
            found = centre_units(self, display, centre, lighting, lengths, settings.seed, ccm,
                                 spectral, stop, progress)
        else:
            display = display_spec_for_config(cfg)
            renderer = Renderer.shared(capacity_for(display.rows * display.cols))
            step = stepper("simulating the display")
            step(0, 1)
            spectral = self.transport(display, lighting)
            units_of = viewpoint_units if source == "viewpoints" else audience_units
            found = units_of(self, renderer, display, lighting, lengths, settings, ccm,
                             spectral, step)
        t_sim = time.perf_counter() - t_start
        units, unit_of_pixel = list(found.units), found.unit_of_pixel
        viewers = found.viewers.split_by_table(unit_of_pixel)  # each table on its own pixels
        for u in units:  # one check per table (controllers or pixel groups), never per pixel
            try:
                check_shape(u.characteristic.lengths_mm, u.characteristic.ogcd,
                            u.characteristic.ogcd_stderr, cc.max_flat_fraction,
                            u.step_stderr)
            except CalibrationRejected as exc:
                raise CalibrationRejected(f"{u.name}: {exc}") from None
        checked = _TableChecks(cfg, unit_of_pixel, found.whole, previous_um, previous_tables,
                               force, own_tables=source != CENTRE)
        checked(units)  # the first tables, before the closed loop spends time on them
        t_loop = time.perf_counter()
        units, rounds = closed_loop(renderer, display, lighting, viewers, units, unit_of_pixel,
                                    settings, ccm, spectral, cc, checked, stepper)
        controller_tables, max_step = checked(units)
        whole = found.whole if found.whole is not None else units[0]
        total = time.perf_counter() - t_start
        result = CalibrationResult(
            granularity=cfg.tables.granularity, source=source,
            shape=(display.rows, display.cols), table_um=whole.lengths_um,
            controller_tables=controller_tables, units=units, unit_of_pixel=unit_of_pixel,
            ccm=ccm, ccm_source=ccm_source,
            lighting_notes=tuple(getattr(lighting, "notes", ())), grouping=found.grouping,
            region=found.region, loop_rounds=rounds,
            seconds={"simulate": t_sim, "closed_loop": total - (t_loop - t_start),
                     "total": total},
            max_step_um=max_step, curves=found.curves, transport=cfg.simulation.transport)
        return with_correction(cfg, result, correction)


class _TableChecks:
    """The table checks of a run (:func:`grassd.daemon.core.calibration.checks.check_table`), run
    on its first tables and again after every refinement: every controller's table against its
    own previous one (or the active display-wide table when it had none of that shape); the
    display-wide table once, against the active one when it is what every controller gets (a
    run with no tables of its own, ``own_tables`` False: a centre-pixel run's table is every
    controller's)."""

    def __init__(self, cfg: Config, unit_of_pixel: NDArray, whole: UnitTable | None,
                 previous_um: NDArray | None, previous_tables: Mapping[str, NDArray] | None,
                 force: bool, own_tables: bool) -> None:
        self.cfg, self.unit_of_pixel, self.whole = cfg, unit_of_pixel, whole
        self.own_tables = own_tables
        self.previous_um, self.previous_tables, self.force = previous_um, previous_tables, force
        self.whole_step: int | None = None
        if whole is not None:  # never refined: checked once
            self.whole_step = self._check(whole.lengths_um, None, "display-wide table")

    def _check(self, table: NDArray, previous: NDArray | None, what: str) -> int | None:
        cc = self.cfg.calibration
        return check_table(table, self.cfg.display.green_max_mm, previous, cc.max_jump_mm,
                           self.force, what)

    def __call__(self, units: Sequence[UnitTable]) -> tuple[dict[str, NDArray], int | None]:
        """(every controller's table, the largest step [um] from the active tables or None)."""
        tables = (controller_tables_of(self.cfg, units, self.unit_of_pixel)
                  if self.own_tables else {})
        steps = [self.whole_step]
        if self.whole is None:  # the run's one unit is the display-wide table
            steps.append(self._check(units[0].lengths_um, self.previous_um,
                                     "table" if not tables else "display-wide table"))
        for name, table in tables.items():
            prev = None if self.previous_tables is None else self.previous_tables.get(name)
            if prev is not None and np.ndim(prev) != 1 and np.shape(prev) != table.shape:
                prev = None  # its pixel count changed: compare with the display-wide table
            steps.append(self._check(table, prev if prev is not None else self.previous_um,
                                     f"table of controller {name}"))
        known = [s for s in steps if s is not None]
        return tables, max(known) if known else None


def closed_loop(renderer: Renderer, display: DisplaySpec, lighting: Lighting, viewers: Viewers,
                units: list[UnitTable], unit_of_pixel: NDArray, settings: RenderSettings,
                ccm: ColourCorrection | None, spectral: SpectralTransport | None,
                cc: CalibrationConfig, checked: _TableChecks,
                stepper: Callable[[str], Callable[[int, int], None]]
                ) -> tuple[list[UnitTable], list[LoopCheck]]:
    """Up to ``cc.max_rounds`` rounds of :func:`closed_loop_check` (round k with seed
    ``settings.seed + 1000 k``); after each, every unit whose pixels deviate by more than
    ``cc.target_de00`` [dE00] is refined (:func:`refine_unit`, when the viewers carry group
    characteristics) and the tables are ``checked`` again. Returns the units, each with its
    last round's ``loop_max_dev`` and ``loop_r2``, and the rounds."""
    levels = check_levels(cc.check_levels)
    rounds: list[LoopCheck] = []
    for k in range(1, cc.max_rounds + 1):
        pixel_tables = np.stack([u.lengths_um for u in units])[unit_of_pixel]
        loop = closed_loop_check(renderer, display, lighting, viewers, pixel_tables, levels,
                                 replace(settings, seed=settings.seed + 1000 * k), ccm,
                                 stepper(f"closed loop round {k}"), round_no=k,
                                 spectral=spectral)
        rounds.append(loop)
        pixel_dev = loop.pixel_dev()
        off = [i for i, u in enumerate(units)
               if u.pixels.size and pixel_dev[u.pixels].max() > cc.target_de00]
        log.info("closed loop round %d: max deviation %.3f dE00, R^2 %.5f, %d of %d "
                 "tables above %.2f", k, float(loop.max_dev.max()), float(loop.r2.min()),
                 len(off), len(units), cc.target_de00)
        if not off or k == cc.max_rounds or viewers.group_characteristics is None:
            break
        for i in off:  # every round so far measured the unit's table of its time
            units[i] = refine_unit(units[i], rounds, viewers.group_characteristics)
        checked(units)
    pixel_dev, pixel_r2 = loop.pixel_dev(), loop.r2[loop.labels]
    units = [replace(u, loop_max_dev=float(pixel_dev[u.pixels].max()),
                     loop_r2=float(pixel_r2[u.pixels].min())) if u.pixels.size else u
             for u in units]
    return units, rounds


def closed_loop_check(renderer: Renderer, display: DisplaySpec, lighting: Lighting,
                      viewers: Viewers, pixel_tables_um: NDArray, levels: NDArray,
                      settings: RenderSettings, ccm: ColourCorrection | None,
                      step: Callable[[int, int], None],
                      round_no: int = 1, spectral: SpectralTransport | None = None
                      ) -> LoopCheck:
    """Re-simulate every group's representative pixel from every viewer at the lengths its
    table gives ``levels`` (``pixel_tables_um`` (N, 256) [um], first level 0 = the reference
    length), average the viewers' OGCD with their weights and compare it with the linear
    target ``level / 255 x OGCD(255)`` (the check of the global run's closed loop).
    ``settings`` carries the round's own seed; ``spectral``: the run's transport. One trace
    per (group, viewer)."""
    w = viewers.weights / viewers.weights.sum()
    reps = viewers.representatives
    lx = pixel_tables_um[reps][:, levels].astype(np.float64) / 1000.0  # (G, L) mm
    total = len(reps) * len(w)
    ogcd = np.empty_like(lx)
    se = np.empty_like(lx)
    done = 0
    for g, p in enumerate(reps):  # one trace per group and viewer, never per pixel
        ys, es = [], []
        for vp in viewers.viewpoints_of(int(p)):
            c = simulate_curve(renderer, display, lighting, vp, lx[g], settings, ccm=ccm,
                               pixel_index=int(p), layouts=viewers.layouts,
                               spectral=spectral)
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
    (:meth:`Calibrator.run`). The errors are re-measured on the
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
    r2b, r2a = r2_pair(fit, table.lengths_um)
    return replace(u, lengths_um=np.asarray(table.lengths_um, np.uint16),
                   max_error=float(errs.max()), mean_error=float(w @ errs), r2_before=r2b,
                   r2_after=r2a, ogcd_range=float(fit.ogcd_range), refined_rounds=len(loops))
