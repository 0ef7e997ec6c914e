"""Scene parameters: the grass pixel, the display that tiles it, the viewpoint, render settings.

Units: millimetres for pixel dimensions (as the paper gives them), centimetres for eye height,
metres for viewing distance, degrees for angles. The world frame used by the renderer is metres,
z up, +x east, +y north; the display surface (the base top of every pixel) is the plane z = 0 and
pixel (0, 0) is centred on the origin.

Viewpoint convention (paper, section 4.1): the eye is ``h_cm`` above the display surface plane at
horizontal distance ``d_m`` from the pixel centre; ``theta_deg`` = 0 puts the eye on the -y axis,
looking across the slits (the slits run along x). Positive theta turns the eye towards +x::

    eye = (d sin(theta), -d cos(theta), h / 100)   [m]
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from grassd.sim.errors import SceneError

if TYPE_CHECKING:  # numpy inside the functions: parsing a configuration (its PixelSpec)
    # needs none, and ``grassd status`` starts without it
    import numpy as np


def srgb_to_linear(srgb8: tuple[float, float, float]) -> np.ndarray:
    """Linearise an 8-bit encoded sRGB colour (IEC 61966-2-1 transfer curve) to linear Rec.709.

    >>> srgb_to_linear((255, 255, 255)).round(6).tolist()
    [1.0, 1.0, 1.0]
    """
    import numpy as np

    c = np.asarray(srgb8, dtype=np.float64) / 255.0
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


@dataclass(frozen=True)
class PixelSpec:
    """Geometry and materials of one grass pixel (defaults: the paper, section 3.2.2).

    Lengths in mm, densities in blades per mm^2, albedos as 8-bit encoded sRGB as a colour
    reader reports them (linearised when the scene is built). ``specular`` adds a glossy lobe
    to every surface (achromatic reflectance, 0 = off, the default: the paper's materials are
    diffuse with metallic 0); ``smoothness`` (0..1, Unity-style) sets its sharpness.

    The default albedos are plausible values for yellow and green artificial grass and a yellow
    3D-printed base; replace them with your own measurements (the paper used a Datacolor
    ColorReader CR100).
    """

    top_mm: float = 33.5
    base_height_mm: float = 15.0
    yellow_height_mm: float = 10.0
    slit_width_mm: float = 5.7
    slit_count: int = 3
    slit_length_mm: float = 30.0
    green_max_mm: float = 20.0
    blade_width_mm: float = 1.2
    blade_tip_ratio: float = 0.3
    taper_mm: float = 4.0
    yellow_density: float = 0.35
    green_density: float = 0.45
    jitter: float = 0.15
    yellow_lean_deg: float = 12.0
    green_lean_deg: float = 6.0
    splay_deg: float = 0.0
    cavity_depth_mm: float = 15.0
    yellow_srgb: tuple[float, float, float] = (196.0, 176.0, 72.0)
    green_srgb: tuple[float, float, float] = (62.0, 118.0, 46.0)
    base_srgb: tuple[float, float, float] = (180.0, 160.0, 66.0)
    cavity_srgb: tuple[float, float, float] = (30.0, 30.0, 30.0)
    specular: float = 0.0
    smoothness: float = 0.5
    layout_seed: int = 1

    def __post_init__(self) -> None:
        positive = {
            "top_mm": self.top_mm,
            "base_height_mm": self.base_height_mm,
            "blade_width_mm": self.blade_width_mm,
            "taper_mm": self.taper_mm,
            "green_max_mm": self.green_max_mm,
            "cavity_depth_mm": self.cavity_depth_mm,
        }
        for name, value in positive.items():
            if not (math.isfinite(value) and value > 0):
                raise SceneError(f"PixelSpec.{name} must be a positive number of mm, got {value!r}")
        for name in ("yellow_height_mm", "yellow_density", "green_density", "slit_width_mm"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise SceneError(f"PixelSpec.{name} must be >= 0, got {value!r}")
        if self.slit_count < 0 or self.slit_count * self.slit_width_mm >= self.top_mm:
            raise SceneError(
                f"PixelSpec: {self.slit_count} slits of {self.slit_width_mm} mm do not fit on a "
                f"{self.top_mm} mm pixel"
            )
        if self.slit_length_mm > self.top_mm:
            raise SceneError("PixelSpec.slit_length_mm must not exceed top_mm")
        if not 0 < self.blade_tip_ratio <= 1:
            raise SceneError("PixelSpec.blade_tip_ratio must be in (0, 1]")
        if not 0 <= self.specular < 1:
            raise SceneError("PixelSpec.specular (glossy reflectance) must be in [0, 1)")
        if not 0 <= self.smoothness <= 0.97:
            raise SceneError("PixelSpec.smoothness must be in [0, 0.97]")
        if not 0 <= self.jitter < 0.5:
            raise SceneError("PixelSpec.jitter must be in [0, 0.5)")
        for name in ("yellow_lean_deg", "green_lean_deg", "splay_deg"):
            if not 0 <= getattr(self, name) < 60:
                raise SceneError(f"PixelSpec.{name} must be in [0, 60) degrees")
        for name in ("yellow_srgb", "green_srgb", "base_srgb", "cavity_srgb"):
            rgb = getattr(self, name)
            if len(rgb) != 3 or not all(0 <= c <= 255 for c in rgb):
                raise SceneError(f"PixelSpec.{name} must be three 8-bit sRGB values in 0..255")

    @property
    def albedo_linear(self) -> np.ndarray:
        """(4, 3) linear Rec.709 albedos of the materials in the renderer's order: yellow,
        green, base, cavity."""
        return srgb_to_linear((self.yellow_srgb, self.green_srgb, self.base_srgb,
                               self.cavity_srgb))

    @property
    def phong_exponent(self) -> float:
        """Exponent of the glossy lobe: ``2 / a^2 - 2`` with roughness ``a = (1 - smoothness)^2``
        (the usual Phong-Beckmann correspondence; smoothness 0.5 gives 30)."""
        a = max((1.0 - self.smoothness) ** 2, 1e-3)
        return max(2.0 / (a * a) - 2.0, 1.0)

    def slit_centres_mm(self) -> np.ndarray:
        """Centres (y, mm) of the slits, evenly spread across the pixel."""
        import numpy as np

        pitch = self.top_mm / max(self.slit_count, 1)
        return (np.arange(self.slit_count) + 0.5) * pitch - self.top_mm / 2


@dataclass(frozen=True)
class DisplaySpec:
    """``rows`` x ``cols`` pixels at ``pitch_mm`` (centre to centre); one pixel is the default.

    Every pixel draws its own random blade layout (as real tufts differ) unless
    ``same_layout``, which copies pixel 0's layout to all (differences then come from viewing
    geometry and neighbours only)."""

    pixel: PixelSpec = field(default_factory=PixelSpec)
    rows: int = 1
    cols: int = 1
    pitch_mm: float = 33.5
    same_layout: bool = False

    def __post_init__(self) -> None:
        if self.rows < 1 or self.cols < 1 or self.rows * self.cols > 4096:
            raise SceneError(f"DisplaySpec: rows x cols must be 1..4096 pixels, got "
                             f"{self.rows} x {self.cols}")
        if self.pitch_mm < self.pixel.top_mm:
            raise SceneError(f"DisplaySpec.pitch_mm {self.pitch_mm} is smaller than the pixel "
                             f"top {self.pixel.top_mm} mm: pixels would overlap")

    def pixel_centres_m(self) -> np.ndarray:
        """(rows*cols, 2) xy centres in metres; row 0 is nearest the viewer at theta = 0 (-y)."""
        import numpy as np

        r, c = np.meshgrid(np.arange(self.rows), np.arange(self.cols), indexing="ij")
        x = (c - (self.cols - 1) / 2) * self.pitch_mm
        y = (r - (self.rows - 1) / 2) * self.pitch_mm
        return np.stack([x.ravel(), y.ravel()], axis=1) / 1000.0


@dataclass(frozen=True)
class Viewpoint:
    """Eye position (h cm above the display plane, d m away, theta deg), paper section 4.1."""

    h_cm: float = 170.0
    d_m: float = 2.0
    theta_deg: float = 0.0

    def __post_init__(self) -> None:
        if not all(math.isfinite(v) for v in (self.h_cm, self.d_m, self.theta_deg)):
            raise SceneError(f"viewpoint {self.label()} must be finite numbers")
        if not 0 < self.h_cm <= 100_000:
            raise SceneError(f"viewpoint {self.label()}: eye height must be above the display "
                             f"plane and at most 1 km (0 < h <= 100000 cm)")
        if not 0 < self.d_m <= 1000:
            raise SceneError(f"viewpoint {self.label()}: distance must be in (0, 1000] m")
        if not -180 <= self.theta_deg <= 180:
            raise SceneError(f"viewpoint {self.label()}: theta must be in [-180, 180] deg")

    def label(self) -> str:
        """``(h, d, theta)`` as the paper writes it."""
        return f"({self.h_cm:g}, {self.d_m:g}, {self.theta_deg:g})"

    def eye_m(self, target_xy_m: tuple[float, float] = (0.0, 0.0)) -> np.ndarray:
        """Eye position in world metres for a pixel centred at ``target_xy_m``."""
        import numpy as np

        t = math.radians(self.theta_deg)
        return np.array([target_xy_m[0] + self.d_m * math.sin(t),
                         target_xy_m[1] - self.d_m * math.cos(t),
                         self.h_cm / 100.0])

    @classmethod
    def parse(cls, text: str) -> Viewpoint:
        """Parse ``"H,D,THETA"`` (cm, m, deg), e.g. ``"170,2,0"``."""
        try:
            h, d, theta = (float(p) for p in text.split(","))
        except ValueError:
            raise SceneError(
                f"viewpoint {text!r} must be H,D,THETA (cm, m, deg), e.g. 170,2,0"
            ) from None
        return cls(h, d, theta)


MAX_REPLICATES = 64  #: replicates of one render (an adaptive run adds rounds of at most this)
MAX_SAMPLES = 4_000_000  #: camera paths of one replicate (within the renderer's buffer, 2^22)
MAX_BOUNCES = 64  #: the most surface interactions a path may have (RenderSettings.max_bounces)


@dataclass(frozen=True)
class RenderSettings:
    """Monte Carlo settings.

    ``samples`` camera paths per length per replicate (rounded up to a square for
    stratification), ``replicates`` independent randomisations whose spread gives the standard
    error (one alone gives none: a top-up batch of an adaptive run), ``max_bounces`` surface
    interactions per path (1 = direct light only; Mitsuba's ``max_depth`` is
    ``max_bounces + 1``; by default :data:`MAX_BOUNCES`, so Russian roulette alone ends a path
    and the estimate is unbiased: a path survives to the 64th surface with probability
    ``0.5**62``, while any cut at a few bounces darkens a pale pixel's colour),
    ``seed`` makes results bit-reproducible,
    ``light_samples`` environment samples (shadow rays) at the first surface a path meets (one
    at later ones), ``roulette_from`` the surface (0 = the first a path meets) from which on
    Russian roulette may end a path (:mod:`grassd.sim.renderer` gives the measurements behind
    both defaults).
    """

    samples: int = 4096
    replicates: int = 8
    max_bounces: int = MAX_BOUNCES
    seed: int = 0
    light_samples: int = 4
    roulette_from: int = 2

    def __post_init__(self) -> None:
        if not 1 <= self.samples <= MAX_SAMPLES:
            raise SceneError(f"samples must be in 1..{MAX_SAMPLES}, got {self.samples}")
        if not 1 <= self.replicates <= MAX_REPLICATES:
            raise SceneError(f"replicates must be in 1..{MAX_REPLICATES}, got {self.replicates}")
        if not 1 <= self.max_bounces <= MAX_BOUNCES:
            raise SceneError(f"max_bounces must be in 1..{MAX_BOUNCES}, got {self.max_bounces}")
        if not 1 <= self.light_samples <= 16:
            raise SceneError(f"light_samples must be in 1..16, got {self.light_samples}")
        if not 1 <= self.roulette_from <= 16:
            raise SceneError(f"roulette_from must be in 1..16, got {self.roulette_from}")
        if not 0 <= self.seed < 2**31:
            raise SceneError(f"seed must be in 0..2^31-1, got {self.seed}")

    @property
    def strata(self) -> int:
        """Side of the stratification grid: samples per replicate = strata**2."""
        return max(1, math.ceil(math.sqrt(self.samples)))


def parse_lengths(text: str) -> np.ndarray:
    """Parse ``START:STOP:STEP`` (inclusive stop) or a comma list, in mm.

    >>> parse_lengths("0:20:5").tolist()
    [0.0, 5.0, 10.0, 15.0, 20.0]
    >>> parse_lengths("0,5,12.5").tolist()
    [0.0, 5.0, 12.5]
    """
    import numpy as np

    try:
        if ":" in text:
            start, stop, step = (float(p) for p in text.split(":"))
            if step <= 0 or stop < start:
                raise ValueError
            n = int(math.floor((stop - start) / step + 1e-9)) + 1
            values = start + step * np.arange(n)
        else:
            values = np.array([float(p) for p in text.split(",")])
    except ValueError:
        raise SceneError(f"lengths {text!r} must be START:STOP:STEP in mm (e.g. 0:20:1) or a "
                         f"comma list (e.g. 0,5,12.5)") from None
    return values
