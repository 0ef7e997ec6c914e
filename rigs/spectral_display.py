"""The display as the measuring camera sees it in a world grassd did not render.

:mod:`.simulated_display` paints grassd's own pixel models into the camera's view, so
``grassd measure`` there fits its models to their own renders. Here the whole display is
exported (:func:`grassd.sim.export.export_display`: every pixel with its own tuft layout, its
hidden length offset and its faded albedos, the layouts of :data:`REAL_LAYOUT_SEED`, never the
model's) and rendered by Mitsuba's spectral path tracer from the camera's position
(:mod:`.spectral_world`: Russian roulette, no depth cut, the albedos and the map upsampled to
smooth spectra), read through a real camera's spectral sensitivities
(:class:`~grassd.rigs.spectral_camera.SpectralCamera`) and the CIE observer. The set-up shot
is the ColorChecker's measured spectra rendered under the same map, its reference values the
spectra's own CIELAB (:func:`~grassd.rigs.spectral_world.write_chart_csv`).

Each pixel's mean over its measurement quad is rendered once per commanded length on a grid
(:attr:`SpectralDisplay.grid_mm`, the offsets added by the pixels themselves), so a shot costs
no rendering: the camera's raw response at the motors' lengths (monotone cubic interpolation
between grid lengths) painted into its equirectangular view
(:func:`grassd.sim.display_photo.display_photo`), served as a DNG with the camera's own
profile (:class:`~grassd.rigs.simulated_camera.SensorView`). Its JPEG shows the same view in
Rec.709 from the CIE observer's channels.

:meth:`SpectralDisplay.prophoto` is the truth a measurement is judged by: every pixel as the
CIE observer sees it from the camera, white-balanced to a white card under the same light.

Units: lengths mm, positions m (display frame), radiance in grassd's units (the white card's
luminance matched to :func:`grassd.daemon.core.calibration.simulation.white_radiance`).
"""

from __future__ import annotations

import shutil
import threading
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from grassd.daemon.core.calibration.variation import DisplayVariation
from grassd.rigs.simulated_display import (
    FRAME_ALBEDO,
    REAL_LAYOUT_SEED,
    SIM_CAMERA_M,
    SIM_CAMERA_WIDTH,
    SIM_CAMERA_YAW_DEG,
    checker_corners,
)
from grassd.rigs.spectral_world import SpectralWorldError

#: Commanded lengths between two renders of the display (mm).
GRID_STEP_MM: float = 1.0
#: Film width of each render of the display (pixels; square, framing every quad).
IMAGE_SIZE: int = 512


class SpectralDisplay:
    """The display photographed by a spectral camera (module docstring): a drop-in for
    :class:`~grassd.rigs.simulated_display.SimulatedDisplay`.

    ``cfg``: the daemon's Config (display size, pixel); ``lighting``: the site's light;
    ``variation``: the pixels' hidden departures; ``positions_um``: the motors' positions (N,)
    in micrometres; ``work_dir``: where the exported scenes and the chart CSV go;
    ``camera``: a :data:`~grassd.rigs.spectral_camera.CAMERAS` name; ``spp``: Mitsuba samples
    per film pixel (each quad covers about a thousand). ``checker``: while True, the camera
    sees the colour checker lying at the display instead (the set-up shot).
    """

    def __init__(self, cfg: Any, lighting: Any, variation: DisplayVariation,
                 positions_um: Callable[[], NDArray], work_dir: str | Path, *,
                 camera: str = "nikon-d5100", camera_m: tuple[float, float, float] = SIM_CAMERA_M,
                 yaw_deg: float = SIM_CAMERA_YAW_DEG, width: int = SIM_CAMERA_WIDTH,
                 spp: int = 64, grid_step_mm: float = GRID_STEP_MM,
                 progress: Callable[[int, int], None] | None = None) -> None:
        from grassd.calib.colour_spaces import M_REC709_TO_XYZ
        from grassd.daemon.core.calibration.simulation import white_radiance
        from grassd.rigs.spectral_camera import SpectralCamera
        from grassd.rigs.spectral_world import write_chart_csv
        from grassd.sim.scene import DisplaySpec, PixelSpec

        d = cfg.display
        pixel = replace(PixelSpec(**dict(d.pixel)), layout_seed=REAL_LAYOUT_SEED)
        self.display = DisplaySpec(pixel, d.rows, d.cols, d.pitch_mm, same_layout=False)
        n = d.rows * d.cols
        if variation.n_pixels != n:
            raise ValueError(f"variation of {variation.n_pixels} pixels for a display of {n}")
        self.lighting, self.variation, self.positions_um = lighting, variation, positions_um
        self.camera = SpectralCamera(camera)
        self.camera_m = np.asarray(camera_m, dtype=np.float64)
        self.yaw_deg, self.width = float(yaw_deg), int(width)
        self.work_dir = Path(work_dir)
        self.work_dir.mkdir(parents=True, exist_ok=True)
        self.chart = str(write_chart_csv(self.work_dir / "chart.csv"))
        gmax = float(pixel.green_max_mm)
        self.grid_mm = np.linspace(0.0, gmax, int(round(gmax / grid_step_mm)) + 1)
        raw, xyz, white_raw, white_xyz, self._checker_raw, self._checker_xyz = \
            self._render(spp, progress)
        white = white_radiance(lighting)
        # one scale for every channel: the white card's luminance as grassd's
        self.xyz_scale = float((M_REC709_TO_XYZ @ white)[1] / white_xyz[1])
        self.raw_scale = float((M_REC709_TO_XYZ @ white)[1] / white_raw[1])
        self.white_xyz = white_xyz * self.xyz_scale
        self.white_raw = white_raw * self.raw_scale
        self._raw = self._interpolator(raw * self.raw_scale)
        self._xyz = self._interpolator(xyz * self.xyz_scale)
        self.checker = False
        self.shots = 0
        self._lock = threading.Lock()

    def _render(self, spp: int, progress: Callable[[int, int], None] | None) -> tuple:
        """Every pixel's quad mean (raw and XYZ, (K, N, 3)) at each grid length, the white
        card's (3,) and the checker's patches (24, 3), in Mitsuba's units."""
        from grassd.calib.regions import extract_checker_patches
        from grassd.rigs.mitsuba_scene import quad_coverage
        from grassd.rigs.spectral_world import render_checker, render_pixel, render_white_card
        from grassd.sim.export import export_display

        v = self.variation
        n = v.n_pixels
        base = self.display.pixel.albedo_linear
        green, yellow = v.albedos(base[1], base[0])
        albedo = np.broadcast_to(base, (n, *base.shape)).copy()
        albedo[:, 0], albedo[:, 1] = yellow, green
        gmax = float(self.display.pixel.green_max_mm)
        scene_dir = self.work_dir / "display"
        raw, xyz = [], []
        for k, c in enumerate(self.grid_mm):
            lengths = np.clip(c + v.length_offset_mm, 0.0, gmax)
            shutil.rmtree(scene_dir, ignore_errors=True)
            doc = export_display(scene_dir, self.display, self.lighting, self.camera_m,
                                 lengths, albedo, image_size=IMAGE_SIZE)
            cams, img_xyz = render_pixel(scene_dir, [self.camera], spp, IMAGE_SIZE, seed=k)
            means = []
            for quad in doc["quads"]:
                (x0, y0), w = quad_coverage({"camera": doc["camera"], "quad": quad}, IMAGE_SIZE)
                win = np.s_[y0:y0 + w.shape[0], x0:x0 + w.shape[1]]
                means.append([np.einsum("hwc,hw->c", im[win], w) / w.sum()
                              for im in (cams[0], img_xyz)])
            raw.append([m[0] for m in means])
            xyz.append([m[1] for m in means])
            if progress is not None:
                progress(k + 1, len(self.grid_mm) + 1)
        (white_raw,), white_xyz = render_white_card(scene_dir, [self.camera], spp=16 * spp)
        (img_raw,), img_xyz, corners = render_checker(scene_dir, [self.camera])
        if progress is not None:
            progress(len(self.grid_mm) + 1, len(self.grid_mm) + 1)
        shutil.rmtree(scene_dir, ignore_errors=True)
        patches = [extract_checker_patches(im, corners) for im in (img_raw, img_xyz)]
        return np.asarray(raw), np.asarray(xyz), white_raw, white_xyz, *patches

    def _interpolator(self, values: NDArray) -> Callable[[NDArray], NDArray]:
        """(N,) commanded lengths (mm) -> (N, 3): monotone cubic between grid lengths."""
        from scipy.interpolate import PchipInterpolator

        f = PchipInterpolator(self.grid_mm, values, axis=0)  # (K, N, 3)
        idx = np.arange(values.shape[1])

        def at(lengths_mm: NDArray) -> NDArray:
            x = np.clip(np.asarray(lengths_mm, dtype=np.float64), self.grid_mm[0],
                        self.grid_mm[-1])
            return f(x)[idx, idx]  # pixel i at its own length

        return at

    def prophoto(self, lengths_mm: NDArray) -> NDArray[np.float64]:
        """(N, 3) linear ProPhoto RGB of every pixel commanded to ``lengths_mm`` (N,) as the
        CIE observer sees it from the camera, white-balanced to a white card under the same
        light (Bradford; the card's Y = 1): what a colorimetric camera would develop."""
        import colour

        from grassd.calib.colour_spaces import M_XYZ_TO_PROPHOTO, WHITE_D50_XY

        w = self.white_xyz / self.white_xyz[1]
        d50 = colour.xy_to_XYZ(WHITE_D50_XY)
        xyz = colour.adaptation.chromatic_adaptation_VonKries(
            self._xyz(lengths_mm) / self.white_xyz[1], w, d50, transform="Bradford")
        return xyz @ M_XYZ_TO_PROPHOTO.T

    def _commanded(self) -> NDArray[np.float64]:
        return np.asarray(self.positions_um(), dtype=np.float64) / 1000.0

    def scene(self) -> Any:
        """The camera's view now: a :class:`~grassd.rigs.simulated_camera.SensorView` (the
        Rec.709 view and the camera's raw response, (H, W, 3) each), a ``SimCamera``'s
        ``scene_source``."""
        from grassd.calib.checker_photo import CHART_BODY_ALBEDO, checker_image
        from grassd.calib.colour_spaces import M_REC709_TO_XYZ, M_XYZ_TO_REC709
        from grassd.rigs.simulated_camera import SensorView
        from grassd.sim.display_photo import display_photo

        profile = self.camera.xyz_to_camera
        with self._lock:
            self.shots += 1
            h = self.width // 2
            if self.checker:
                views = [checker_image(p, CHART_BODY_ALBEDO * w, self.width, h)[0]
                         for p, w in ((self._checker_xyz * self.xyz_scale, self.white_xyz),
                                      (self._checker_raw * self.raw_scale, self.white_raw))]
                return SensorView(views[0] @ M_XYZ_TO_REC709.T, views[1], profile)
            lengths = self._commanded()
            env = np.asarray(self.lighting.env, dtype=np.float64)
            env_xyz = env @ M_REC709_TO_XYZ.T
            views = [display_photo(e, self.camera_m, self.yaw_deg, self.display, px,
                                   frame_radiance=FRAME_ALBEDO * w, width=self.width, height=h)
                     for e, px, w in ((env_xyz, self._xyz(lengths), self.white_xyz),
                                      (env_xyz @ profile.T, self._raw(lengths), self.white_raw))]
            return SensorView((views[0] @ M_XYZ_TO_REC709.T).astype(np.float32),
                              np.clip(views[1], 0.0, None).astype(np.float32), profile)

    def checker_corners(self) -> list[list[float]]:
        """The checker's patch-area corners in the set-up shot
        (:func:`grassd.rigs.simulated_display.checker_corners`)."""
        return checker_corners(self.width)


#: The variation fields a measurement estimates, as its report names them.
FIELDS: tuple[str, ...] = ("length_offset_mm", "green_gain", "yellow_gain")


@dataclass(frozen=True)
class SpectralMeasurement:
    """One ``grassd measure`` of the spectral world's display and the truth it is judged by.

    ``report``: the measurement's report; ``correlation``: per field of :data:`FIELDS`, the
    recovered values' correlation with the truth; ``worst_pair``: the worst pixel pair at
    mid level (dE00) as the CIE observer sees the display from the camera, each pixel's
    viewing geometry divided out as the report does, for the tables without correction
    (``before``), with the measured correction (``measured``) and with the true variation
    corrected the same way (``truth``, the ceiling the tufts' layouts leave);
    ``checker_de00``: the set-up's colour correction, leave-one-out mean and max dE00."""

    report: dict[str, Any]
    correlation: dict[str, float]
    worst_pair: dict[str, float]
    checker_de00: tuple[float, float]


def measure_spectral_world(root: str | Path, variation: DisplayVariation, lux: float = 5000.0,
                           *, camera: str = "nikon-d5100", spp: int = 64
                           ) -> SpectralMeasurement:
    """Render the embedded default config's display with ``variation`` in the spectral world
    (:class:`SpectralDisplay`, under ``root``), make the measuring camera's set-up there, run
    one ``grassd measure`` on simulated controllers and judge it (:class:`SpectralMeasurement`)."""
    import json

    from colour.difference import delta_E

    from grassd.daemon.core.calibration.correction import DisplayCorrection
    from grassd.daemon.core.calibration.display_model import display_spec_for_config
    from grassd.daemon.core.config.settings import load_default_config
    from grassd.daemon.core.runtime.scheduled import scheduled_input
    from grassd.daemon.core.runtime.service import Service
    from grassd.daemon.core.store.layout import StateLayout
    from grassd.daemon.measure.cli import measuring_site, site_lighting
    from grassd.daemon.measure.job import measure_with
    from grassd.daemon.measure.run import (
        MID_LEVEL,
        PixelModels,
        correction_for,
        level_lengths_mm,
        normalised_lab,
    )
    from grassd.rigs import FIRMWARE_BACKENDS
    from grassd.rigs.simulated_site import start_simulated_site

    root = Path(root)
    hw, cfg, transform = start_simulated_site(load_default_config(state_dir=root / "state"),
                                              lux, FIRMWARE_BACKENDS[0])
    n = cfg.display.rows * cfg.display.cols
    try:
        world = SpectralDisplay(cfg, site_lighting(cfg, lux), variation, hw.positions_um,
                                root / "world", camera=camera, spp=spp)
        cfg, _, cam = measuring_site(hw, cfg, transform, world, lux)
        svc = Service(cfg)
        try:
            report = measure_with(svc, "request")
            if report["status"] != "ok":
                raise SpectralWorldError(f"the measurement failed: {report.get('error')}")
            # the same tables without correction, and the truth corrected as the fit was
            inp = scheduled_input(svc.history, svc.inbox, True, svc._resolve_lux)
            nominal = svc.calibrator.run(inp.light, correction=None)
            models = PixelModels.for_measurement(
                cfg, inp.light, replace(display_spec_for_config(cfg), same_layout=True),
                lambda _: None)
            exact = correction_for(cfg, models, variation, "truth")
            seen_by = models.from_eye(np.asarray(report["camera"]["position_m"]), "camera",
                                      cfg.measure.layouts)
        finally:
            svc.shutdown()
            cam.stop()
    finally:
        hw.stop()
    layout = StateLayout(cfg.state_dir)
    measured = DisplayCorrection.from_json(json.loads(layout.correction.read_text()))
    got = {f: np.array([p[f] for p in sorted(report["pixels"], key=lambda p: p["index"])])
           for f in FIELDS}
    level = {name: level_lengths_mm(cfg, res, n, MID_LEVEL)
             for name, res in (("before", nominal), ("measured", measured.apply(cfg, nominal)),
                               ("truth", exact.apply(cfg, nominal)))}

    def worst(lengths: NDArray) -> float:
        lab = normalised_lab(world.prophoto(lengths), seen_by, level["before"], np.eye(3))
        return float(delta_E(lab[:, None, :], lab[None, :, :], method="CIE 2000").max())

    mean_de, max_de = json.loads(layout.measure_setup.read_text())["ccm_de00"]
    return SpectralMeasurement(
        report, {f: float(np.corrcoef(got[f], getattr(variation, f))[0, 1]) for f in FIELDS},
        {name: worst(x) for name, x in level.items()}, (float(mean_de), float(max_de)))
