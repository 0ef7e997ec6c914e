"""A virtual camera: linear scene radiance -> a believable Bayer RAW written as a DNG.

Turns a rendered view (linear Rec.709 radiance, e.g. from ``grassd.sim``) into the file a real
camera would have produced, so that the whole real-capture path (LibRaw development, white
balance from a colour checker, exposure normalisation, colour correction) can be exercised
without shipping real photographs. The model, per photosite:

1. Colour: the sensor's native RGB is ``C . XYZ`` (XYZ relative to D65, Y of a white card under
   the scene light as it comes), ``C`` = :attr:`VirtualCamera.xyz_to_camera`. The default ``C`` is
   the published D65 ColorMatrix of a Canon EOS 5D Mark II (Adobe DNG Converter / dcraw
   ``adobe_coeff``), whose primaries differ strongly from ProPhoto. Negative responses (colours
   outside the sensor's gamut of a 3x3 model) are clipped at 0, as a photodiode cannot go below 0.
2. Exposure: fixed for a session, set as a photographer would with a white card: the most
   sensitive channel's response to a perfect diffuse white under the scene light fills
   ``white_fraction`` of the full well (:meth:`VirtualCamera.exposure_for`).
3. Optics: a Gaussian blur of ``blur_px`` pixels (lens and optical low-pass filter). Without
   it, grass blades narrower than a photosite alias in the Bayer mosaic and demosaicing turns
   that into false colour that does not average out (about -3 b* on the yellow grass at 96 px).
4. Bayer sampling (``cfa_pattern``), then photo-electrons with shot noise (Poisson) plus Gaussian
   read noise (electrons), converted to data numbers with ``(white - black) / full_well`` DN per
   electron on top of the black level, rounded and clipped to ``bits``-bit integers
   (12-14 bit, like real sensors).
5. The file: :func:`grassd.calib.dng.write_dng` with ColorMatrix1 = ``profile`` (by default the
   true ``C``; give a different one to model an inaccurate camera profile, which the checker
   colour correction must then remove) and AsShotNeutral = the camera's white-balance estimate
   (default: the sensor's response to the scene white, i.e. a correct as-shot white balance;
   give ``as_shot_neutral`` to model a wrong one).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from grassd.calib.array_checks import as_float_array
from grassd.calib.colour_spaces import M_REC709_TO_XYZ
from grassd.calib.dng import CFA_PATTERNS, DngCamera, write_dng
from grassd.calib.errors import DngWriteError

#: XYZ (D65) -> camera native RGB of a Canon EOS 5D Mark II (DNG ColorMatrix1, D65).
CANON_5D2_XYZ_TO_CAMERA: NDArray[np.float64] = np.array(
    [[0.4716, 0.0603, -0.0830], [-0.7798, 1.5474, 0.2480], [-0.1496, 0.1937, 0.6651]]
)


def _default_matrix() -> NDArray[np.float64]:
    return CANON_5D2_XYZ_TO_CAMERA.copy()


@dataclass(frozen=True)
class VirtualCamera:
    """Sensor, noise and file parameters of a virtual camera (see the module docstring).

    Attributes:
        xyz_to_camera: (3, 3) true sensor response, XYZ (D65-relative) -> native RGB.
        profile: (3, 3) ColorMatrix1 written into the DNG; None = ``xyz_to_camera``.
        cfa_pattern: Bayer layout, one of :data:`grassd.calib.dng.CFA_PATTERNS`.
        bits: ADC bit depth (12..16); the white level is ``2**bits - 1``.
        black_level: DN of zero light; None = ``2**(bits - 5)`` (512 at 14 bit).
        full_well_e: electrons at the white level (sets the shot noise).
        read_noise_e: standard deviation of the read noise (electrons).
        white_fraction: fraction of full scale a white card fills in the brightest channel.
        blur_px: standard deviation (pixels) of a Gaussian lens/optical low-pass blur applied
            before the colour filter array; 0 = none.
        make, model: written to the DNG (LibRaw reports them; validate compares them).
    """

    xyz_to_camera: NDArray[np.float64] = field(default_factory=_default_matrix)
    profile: NDArray[np.float64] | None = None
    cfa_pattern: str = "RGGB"
    bits: int = 14
    black_level: int | None = None
    full_well_e: float = 30000.0
    read_noise_e: float = 3.0
    white_fraction: float = 0.6
    blur_px: float = 1.0
    make: str = "grassd"
    model: str = "Virtual Camera"

    def __post_init__(self) -> None:
        c = np.asarray(self.xyz_to_camera, dtype=np.float64)
        if c.shape != (3, 3) or not np.isfinite(c).all() or abs(np.linalg.det(c)) < 1e-9:
            raise DngWriteError(f"xyz_to_camera must be an invertible 3x3; got {c.tolist()}")
        if not 12 <= self.bits <= 16:
            raise DngWriteError(f"bits must be 12..16 (a real ADC); got {self.bits}")
        if self.cfa_pattern not in CFA_PATTERNS:
            raise DngWriteError(f"unknown CFA pattern {self.cfa_pattern!r}; use one of "
                                f"{', '.join(CFA_PATTERNS)}")
        if not 0 <= self.black_level_dn < self.white_level // 2:
            raise DngWriteError(f"black_level {self.black_level} must be in "
                                f"0..{self.white_level // 2}")
        if not (self.full_well_e > 0 and self.read_noise_e >= 0):
            raise DngWriteError("full_well_e must be > 0 and read_noise_e >= 0 electrons")
        if not 0 <= self.blur_px <= 10:
            raise DngWriteError(f"blur_px must be in 0..10 pixels; got {self.blur_px}")
        if not 0 < self.white_fraction <= 1:
            raise DngWriteError(f"white_fraction must be in (0, 1]; got {self.white_fraction}")

    @property
    def white_level(self) -> int:
        """DN of saturation, ``2**bits - 1``."""
        return (1 << self.bits) - 1

    @property
    def black_level_dn(self) -> int:
        """DN of zero light."""
        return (1 << (self.bits - 5)) if self.black_level is None else int(self.black_level)

    def dng_camera(self) -> DngCamera:
        """The DNG tags this camera writes (profile, CFA, levels, make/model)."""
        profile = self.xyz_to_camera if self.profile is None else self.profile
        return DngCamera(color_matrix=np.asarray(profile, dtype=np.float64),
                         cfa_pattern=self.cfa_pattern, black_level=self.black_level_dn,
                         white_level=self.white_level, make=self.make, model=self.model)

    def camera_rgb(self, rgb709: ArrayLike) -> NDArray[np.float64]:
        """Sensor response (..., 3) to linear Rec.709 radiance (..., 3), clipped at 0."""
        rgb = as_float_array(rgb709, "rgb709", last_dim=3)
        m = np.asarray(self.xyz_to_camera, dtype=np.float64) @ M_REC709_TO_XYZ
        return np.clip(rgb @ m.T, 0.0, None)

    def exposure_for(self, white_rgb709: ArrayLike) -> float:
        """Electrons per unit radiance so a white card of radiance ``white_rgb709`` (3,) fills
        ``white_fraction`` of the full well in its brightest channel."""
        peak = float(self.camera_rgb(np.asarray(white_rgb709, dtype=np.float64)).max())
        if not np.isfinite(peak) or peak <= 0:
            raise DngWriteError(f"the white reference {np.asarray(white_rgb709).tolist()} gives "
                                "no signal; the scene light must be positive")
        return self.white_fraction * self.full_well_e / peak

    def expose(self, rgb709: ArrayLike, electrons_per_unit: float,
               rng: np.random.Generator) -> NDArray[np.uint16]:
        """Bayer raw DN (H, W) uint16 of a linear Rec.709 radiance image (H, W, 3).

        As in scRGB, components may be negative for colours outside the Rec.709 gamut (e.g.
        saturated checker patches); the sensor sees their true XYZ.

        Shot noise ~ Poisson(signal electrons), read noise ~ N(0, read_noise_e); DN rounded and
        clipped to ``0..white_level``.
        """
        img = as_float_array(rgb709, "rgb709", last_dim=3, ndim=3)
        self._check_bayer_size(img)
        if self.blur_px > 0:  # lens + optical low-pass filter: Gaussian, before the CFA
            from scipy.ndimage import gaussian_filter

            img = gaussian_filter(img, sigma=(self.blur_px, self.blur_px, 0), mode="nearest")
        return self._sample(self.camera_rgb(img), electrons_per_unit, rng)

    def expose_camera_rgb(self, camera_rgb: ArrayLike, electrons_per_unit: float,
                          rng: np.random.Generator) -> NDArray[np.uint16]:
        """Bayer raw DN (H, W) uint16 of an image (H, W, 3) of the sensor's own response (e.g.
        integrated from spectra), non-negative; blurred, sampled and digitised as
        :meth:`expose` does after its colour step."""
        img = as_float_array(camera_rgb, "camera_rgb", last_dim=3, ndim=3, non_negative=True)
        self._check_bayer_size(img)
        if self.blur_px > 0:
            from scipy.ndimage import gaussian_filter

            img = gaussian_filter(img, sigma=(self.blur_px, self.blur_px, 0), mode="nearest")
        return self._sample(img, electrons_per_unit, rng)

    @staticmethod
    def _check_bayer_size(img: NDArray) -> None:
        h, w = img.shape[:2]
        if h < 2 or w < 2 or h % 2 or w % 2:
            raise DngWriteError(f"a Bayer image needs an even height and width >= 2; got {h}x{w}")

    def _sample(self, cam: NDArray, electrons_per_unit: float,
                rng: np.random.Generator) -> NDArray[np.uint16]:
        h, w, _ = cam.shape
        pattern = np.array(CFA_PATTERNS[self.cfa_pattern]).reshape(2, 2)
        channel = np.tile(pattern, (h // 2, w // 2))
        plane = np.take_along_axis(cam, channel[..., None], axis=2)[..., 0]
        mean_e = plane * float(electrons_per_unit)
        # cap far above full well: beyond it everything clips anyway (Poisson needs finite lam)
        electrons = rng.poisson(np.minimum(mean_e, 4.0 * self.full_well_e)).astype(np.float64)
        electrons += rng.normal(0.0, self.read_noise_e, size=electrons.shape)
        gain = (self.white_level - self.black_level_dn) / self.full_well_e  # DN per electron
        dn = np.rint(self.black_level_dn + electrons * gain)
        return np.clip(dn, 0, self.white_level).astype(np.uint16)

    def photograph(self, path: str | Path, rgb709: ArrayLike, white_rgb709: ArrayLike, *,
                   electrons_per_unit: float | None = None, seed: int = 0,
                   as_shot_neutral: ArrayLike | None = None) -> Path:
        """Photograph a linear Rec.709 radiance image (H, W, 3) into a DNG at ``path``.

        ``white_rgb709`` (3,) is the radiance of a white card under the scene light: it sets the
        as-shot white balance and, unless ``electrons_per_unit`` is given, the exposure.
        """
        white = as_float_array(white_rgb709, "white_rgb709", last_dim=3, ndim=1,
                               non_negative=True)
        k = self.exposure_for(white) if electrons_per_unit is None else float(electrons_per_unit)
        raw = self.expose(rgb709, k, np.random.default_rng(seed))
        if as_shot_neutral is None:
            n = self.camera_rgb(white)
            as_shot_neutral = n / n.max()
        return write_dng(path, raw, self.dng_camera(), as_shot_neutral=as_shot_neutral)

    def photograph_camera_rgb(self, path: str | Path, camera_rgb: ArrayLike,
                              white_camera: ArrayLike, *, electrons_per_unit: float | None = None,
                              seed: int = 0, as_shot_neutral: ArrayLike | None = None) -> Path:
        """Photograph an image (H, W, 3) of the sensor's own response into a DNG at ``path``;
        ``white_camera`` (3,) is the response to a white card under the scene light (the
        exposure, unless ``electrons_per_unit`` is given, and the as-shot white balance)."""
        white = as_float_array(white_camera, "white_camera", last_dim=3, ndim=1,
                               non_negative=True)
        if white.max() <= 0:
            raise DngWriteError("the white card's response is 0; the scene light must be positive")
        k = (self.white_fraction * self.full_well_e / float(white.max())
             if electrons_per_unit is None else float(electrons_per_unit))
        raw = self.expose_camera_rgb(camera_rgb, k, np.random.default_rng(seed))
        neutral = white / white.max() if as_shot_neutral is None else as_shot_neutral
        return write_dng(path, raw, self.dng_camera(), as_shot_neutral=neutral)
