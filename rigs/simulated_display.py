"""The simulated display as a camera sees it: what ``grassd measure`` photographs in simulation.

The display's pixels carry hidden departures from the model pixel
(:class:`~grassd.daemon.core.calibration.variation.DisplayVariation`, read from
``--sim-display-variation FILE``) and each has its own tuft layout, none of them the layout the
daemon's model uses: what a real display has and grassd cannot know. Their grass stands where the
simulated controllers' motors are (:meth:`SimulatedHardware.positions_um
<grassd.rigs.simulated_site.SimulatedHardware.positions_um>`), so a test pattern, a table
or a controller that fell back to content shows in the photo as it would on site.

Every pixel's radiance from the camera's position is recorded once, as a polynomial in its
materials on a grid of lengths (:func:`grassd.daemon.measure.pixel_model.record_pixel_model`),
so a shot costs no rendering: the radiance at the motors' lengths, painted into the camera's
equirectangular view of the site (:func:`grassd.sim.display_photo.display_photo`).

The simulated measuring camera stands at :data:`SIM_CAMERA_M` (display frame, m), turned by
:data:`SIM_CAMERA_YAW_DEG`; grassd is not told where: it finds the display and solves the pose.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from grassd.daemon.core.calibration.variation import DisplayVariation

#: Where the simulated measuring camera stands: display frame, metres (x along the columns,
#: y along the rows, z up; the display's centre is the origin).
SIM_CAMERA_M: tuple[float, float, float] = (0.10, -0.42, 0.38)
#: How the simulated measuring camera is turned about the vertical (degrees).
SIM_CAMERA_YAW_DEG: float = 25.0
#: Width of its equirectangular shots (texels; its DNG has twice as many photosites per side).
SIM_CAMERA_WIDTH: int = 2048
#: Layout seed of the real pixels (pixel i has seed + i); the daemon's model uses others.
REAL_LAYOUT_SEED: int = 7001
#: Radiance of the display's frame, relative to the white card.
FRAME_ALBEDO: float = 0.04


class SimulatedDisplay:
    """The display photographed by the simulated measuring camera (module docstring).

    ``cfg``: the daemon's Config (display size, pixel); ``lighting``: the site's light;
    ``variation``: the pixels' hidden departures; ``positions_um``: the motors' positions (N,)
    in micrometres, row-major display pixels; ``renderer``: a Renderer with room for the
    display. The pixels' light transport is the daemon's (``[simulation] transport``).
    ``checker``: while True, the camera sees the colour checker lying at the display instead
    (the set-up shot).
    """

    def __init__(self, cfg: Any, lighting: Any, variation: DisplayVariation,
                 positions_um: Callable[[], NDArray], renderer: Any, *,
                 camera_m: tuple[float, float, float] = SIM_CAMERA_M,
                 yaw_deg: float = SIM_CAMERA_YAW_DEG, width: int = SIM_CAMERA_WIDTH,
                 samples: int = 1024,
                 progress: Callable[[int, int], None] | None = None) -> None:
        from grassd.daemon.core.calibration.calibrate import Calibrator
        from grassd.daemon.core.calibration.display_model import geometry_from_eye
        from grassd.daemon.core.calibration.simulation import white_radiance
        from grassd.daemon.measure.pixel_model import record_pixel_model
        from grassd.sim.scene import DisplaySpec, PixelSpec, RenderSettings

        d = cfg.display
        pixel = replace(PixelSpec(**dict(d.pixel)), layout_seed=REAL_LAYOUT_SEED)
        self.display = DisplaySpec(pixel, d.rows, d.cols, d.pitch_mm, same_layout=False)
        if variation.n_pixels != d.rows * d.cols:
            raise ValueError(f"variation of {variation.n_pixels} pixels for a display of "
                             f"{d.rows * d.cols}")
        self.lighting, self.variation, self.positions_um = lighting, variation, positions_um
        self.camera_m = np.asarray(camera_m, dtype=np.float64)
        self.yaw_deg, self.width = float(yaw_deg), int(width)
        self.white = white_radiance(lighting)
        geo = geometry_from_eye(self.display, self.camera_m)
        grid = np.linspace(0.0, pixel.green_max_mm, int(round(pixel.green_max_mm * 2)) + 1)
        self.model = record_pixel_model(
            renderer, self.display, lighting, [geo.viewpoint(i) for i in range(geo.n_pixels)],
            grid, RenderSettings(samples=samples, replicates=4, seed=90_001),
            transport=Calibrator(cfg).transport(self.display, lighting), progress=progress)
        self.checker = False
        self.chart = CHECKER_CHART  # what the set-up shot's checker is (a chart name or CSV)
        self.shots = 0
        self._lock = threading.Lock()

    def pixel_radiance(self) -> NDArray[np.float64]:
        """(N, 3) radiance (nits) of every pixel towards the camera, grass where the motors
        are now."""
        lengths = np.asarray(self.positions_um(), dtype=np.float64) / 1000.0
        return self.model.radiance(lengths[:, None], self.variation)[:, 0]

    def scene(self) -> NDArray[np.float32]:
        """The camera's view now (H, W, 3) linear radiance (nits): a ``SimCamera``'s
        ``scene_source``."""
        from grassd.sim.display_photo import display_photo

        with self._lock:
            self.shots += 1
            h = self.width // 2
            if self.checker:
                return self._checker(h).astype(np.float32)
            img = display_photo(self.lighting.env, self.camera_m, self.yaw_deg, self.display,
                                self.pixel_radiance(), frame_radiance=FRAME_ALBEDO * self.white,
                                width=self.width, height=h)
            return img.astype(np.float32)

    def _checker(self, height: int) -> NDArray[np.float64]:
        from grassd.calib.charts import get_chart
        from grassd.calib.checker_photo import checker_scene

        img, _ = checker_scene(get_chart(CHECKER_CHART), self.white, self.width, height)
        return img

    def checker_corners(self) -> list[list[float]]:
        """The checker's patch-area corners in the set-up shot (:func:`checker_corners`)."""
        return checker_corners(self.width)


def checker_corners(width: int) -> list[list[float]]:
    """The patch-area corners (TL, TR, BR, BL) of the checker a ``width``-texel measuring camera
    photographs, in the full-size developed set-up shot (x, y pixels: twice the texels of the
    camera's view, its DNG's resolution)."""
    from grassd.calib.checker_photo import CHART_LAYOUT

    return (CHART_LAYOUT * np.array([width, width // 2]) * 2).tolist()


#: The chart the simulated operator lays at the display for the set-up shot.
CHECKER_CHART: str = "spydercheckr-24"
