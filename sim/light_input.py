"""What one measurement of the light at the display is, before it becomes a :class:`Lighting`.

Every part that starts from a measured (or assumed) light uses this one type: a bundle manifest
(``grassd.daemon.core.store.ingest``), the calibrator, the capture validation and the paper's
experiments (``grassd.daemon.offline``), the sweep and ``grassd simulate``. It holds readings,
not physics: :meth:`LightInput.lighting` hands them to :func:`grassd.sim.lighting.build_lighting`,
which checks them and builds the scaled map and the sun.

Importing this module loads neither numpy nor Taichi (the daemon's manifest parser uses it).
"""

from __future__ import annotations

from dataclasses import dataclass
from datetime import datetime
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from grassd.sim.lighting import Lighting

__all__ = ["LightInput"]


@dataclass(frozen=True)
class LightInput:
    """One light measurement (the arguments of :func:`grassd.sim.lighting.build_lighting`).

    ``hdri``: the equirectangular panorama (.exr/.hdr) taken with the readings.
    ``ambient_lux`` [lx]: the horizontal reading without the sun (meter shaded), or the total
    reading with ``sun_from_hdri`` (see :func:`build_lighting`); None only while it is still to
    be read from a lux sensor (a bundle whose manifest leaves it out).
    ``sun_lux`` [lx]: horizontal illuminance of the direct sun (reading with minus reading
    without), None without a sun reading. ``sun_azimuth_deg`` / ``sun_elevation_deg`` [deg]:
    compass azimuth (clockwise from north) and elevation of the sun, both or neither.
    ``sun_from_hdri``: find the sun in the map instead. ``rotation_deg`` [deg] / ``flip``: how
    the file is oriented (:func:`grassd.sim.lighting.orient_env`). ``timestamp``: when the light
    was measured (timezone-aware), None when no time belongs to it.
    """

    hdri: Path
    ambient_lux: float | None
    sun_lux: float | None = None
    sun_azimuth_deg: float | None = None
    sun_elevation_deg: float | None = None
    sun_from_hdri: bool = False
    rotation_deg: float = 0.0
    flip: bool = False
    timestamp: datetime | None = None

    def lighting(self, hdri: Any = None, *, max_texels: int | None = None) -> Lighting:
        """The :class:`grassd.sim.lighting.Lighting` of this light (lux-scaled map + sun);
        ``hdri``: the panorama already loaded as an (H, W, 3) array, instead of reading
        :attr:`hdri` again; ``max_texels``: the largest map read from :attr:`hdri` (default
        :data:`grassd.sim.hdri.MAX_TEXELS`; refused from its header beyond). Raises
        :class:`grassd.sim.errors.LightingError` for readings that cannot be (see
        :func:`grassd.sim.lighting.build_lighting`)."""
        from grassd.sim.lighting import build_lighting

        cap = {} if max_texels is None else {"max_texels": max_texels}
        return build_lighting(self.hdri if hdri is None else hdri, self.ambient_lux,
                              sun_lux=self.sun_lux, sun_azimuth_deg=self.sun_azimuth_deg,
                              sun_elevation_deg=self.sun_elevation_deg,
                              sun_from_hdri=self.sun_from_hdri, rotation_deg=self.rotation_deg,
                              flip=self.flip, **cap)
