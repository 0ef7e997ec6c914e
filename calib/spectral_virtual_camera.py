"""A virtual camera whose sensor is defined by non-negative spectral sensitivities.

:class:`grassd.calib.virtual_camera.VirtualCamera` models the sensor as a 3x3 of XYZ; where
that 3x3 is Rec.709's inverse (or any matrix with negative entries) a saturated colour gives a
negative response, which it clips at 0: no photodiode does that, and a checker patch clipped so
bends the colour correction fitted to it. :class:`SpectralVirtualCamera` is the same sensor,
noise and DNG, with a response computed from spectra:

* a spectrum of its own for every linear Rec.709 radiance it is shown: the radiance is taken
  as the scene light's spectrum ``E`` (its ``light``) reflected by a smooth reflectance, the
  albedo ``a = rgb / rgb_E`` (``rgb_E``: the light's Rec.709, Y = 1) spread over Mallett &
  Yuksel's (2019) three non-negative sRGB basis spectra ``B_k`` (colour-science's
  ``MSDS_BASIS_FUNCTIONS_sRGB_MALLETT2019``; they sum to 1, and the albedo's colour under D65
  is ``a``). The response ``c = integral S E sum_k a_k B_k d lambda`` is the 3x3 ``K a`` with
  every entry of ``K`` non-negative (``S``, ``E``, ``B`` all are), so a non-negative radiance
  never reads below 0 and nothing is clipped. Only a radiance with negative components (scRGB
  outside Rec.709, which no light is) can still reach 0, where it is clipped;
* for spectra known as such (a checker's measured reflectances) the exact integral, through
  :func:`spectral_checker_scene` and
  :meth:`~grassd.calib.virtual_camera.VirtualCamera.photograph_camera_rgb`; a chart known only
  by its CIELAB (the SpyderCheckr) gets Jakob & Hanika's (2019) smooth spectra of its colours
  (:func:`chart_reflectances`).

The DNG's profile (ColorMatrix1) is the camera's maker-style matrix
(:attr:`grassd.calib.camera_response.CameraSensitivities.xyz_to_camera`), which the checker's
colour correction then refines, as with a real camera.

References: L. Mallett, C. Yuksel (2019), "Spectral Primary Decomposition for Rendering with
sRGB Reflectance", EGSR; W. Jakob, J. Hanika (2019), "A Low-Dimensional Function Space for
Efficient Spectral Upsampling", Computer Graphics Forum 38(2).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np
from numpy.typing import ArrayLike, NDArray

from grassd.calib.array_checks import as_float_array
from grassd.calib.camera_response import (
    CHECKER_SPECTRA,
    WAVELENGTHS,
    CameraSensitivities,
    checker_reflectances,
    illuminant,
    integrate,
    recover_reflectance,
    reflectance_xyz,
    resample,
)
from grassd.calib.charts import ReferenceChart
from grassd.calib.checker_photo import CHART_BODY_ALBEDO, checker_image
from grassd.calib.colour_spaces import M_XYZ_TO_REC709, lab_to_xyz, xyz_d50_to_d65
from grassd.calib.errors import CameraResponseError
from grassd.calib.virtual_camera import VirtualCamera


def mallett_basis() -> NDArray[np.float64]:
    """(n, 3) Mallett & Yuksel's non-negative sRGB basis spectra on :data:`WAVELENGTHS`."""
    import colour  # on first use: see grassd.calib.colour_spaces

    b = colour.recovery.MSDS_BASIS_FUNCTIONS_sRGB_MALLETT2019
    return resample(b.wavelengths, b.values)


def _nikon() -> CameraSensitivities:
    return CameraSensitivities.from_colour("nikon-d5100")


@dataclass(frozen=True)
class SpectralVirtualCamera(VirtualCamera):
    """A :class:`~grassd.calib.virtual_camera.VirtualCamera` whose colour step is a camera's
    spectral sensitivities (module docstring).

    Attributes (beside the VirtualCamera's; ``xyz_to_camera`` is computed, ``profile``
    defaults to the camera's maker-style matrix):
        sensitivities: the sensor's (non-negative) sensitivities; default colour-science's
            Nikon D5100.
        light: the scene light's spectrum: a name of colour's ``SDS_ILLUMINANTS`` or (n,)
            values on :data:`~grassd.calib.camera_response.WAVELENGTHS`.
        response_matrix: (3, 3) ``K``, albedo (Rec.709 radiance over the light's) -> raw
            response, all entries >= 0; computed.
        light_rgb709: (3,) the light's linear Rec.709 (Y = 1); computed.
    """

    sensitivities: CameraSensitivities = field(default_factory=_nikon)
    light: str | tuple[float, ...] = "D65"
    make: str = "grassd spectral"
    model: str = "Virtual Spectral Camera"
    response_matrix: NDArray[np.float64] = field(init=False, repr=False)
    light_rgb709: NDArray[np.float64] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        light = self.light if isinstance(self.light, str) else tuple(map(float, self.light))
        e = illuminant(light if isinstance(light, str) else np.asarray(light))
        ones = np.ones(len(WAVELENGTHS))
        w = reflectance_xyz(ones, e) @ M_XYZ_TO_REC709.T
        ybar = integrate(e, _cie_y())
        k = integrate((e[:, None] * mallett_basis()).T, self.sensitivities.values) / ybar
        if (k < 0).any() or (w <= 0).any():  # pragma: no cover - guarded by the inputs' checks
            raise CameraResponseError("the light or the sensitivities give a negative response")
        object.__setattr__(self, "light", light)
        object.__setattr__(self, "response_matrix", k.T)
        object.__setattr__(self, "light_rgb709", w)
        # the same response as a 3x3 of XYZ, for the parent's checks and exposure helpers
        object.__setattr__(self, "xyz_to_camera", k.T @ np.diag(1.0 / w) @ M_XYZ_TO_REC709)
        if self.profile is None:
            object.__setattr__(self, "profile", self.sensitivities.xyz_to_camera)
        super().__post_init__()

    def camera_rgb(self, rgb709: ArrayLike) -> NDArray[np.float64]:
        """Sensor response (..., 3) to linear Rec.709 radiance (..., 3) under :attr:`light`:
        ``K (rgb / rgb_light)``; never negative for a non-negative radiance (module
        docstring), negative scRGB inputs clipped at 0."""
        rgb = as_float_array(rgb709, "rgb709", last_dim=3)
        return np.clip((rgb / self.light_rgb709) @ self.response_matrix.T, 0.0, None)

    def response_to_reflectance(self, reflectance: ArrayLike) -> NDArray[np.float64]:
        """Exact response (..., 3) to reflectances (..., n) under :attr:`light`, on the scale of
        :meth:`camera_rgb` (a perfect white reads ``K 1``)."""
        e = illuminant(self.light if isinstance(self.light, str) else np.asarray(self.light))
        return integrate(np.asarray(reflectance, np.float64) * e,
                         self.sensitivities.values) / integrate(e, _cie_y())


def _cie_y() -> NDArray[np.float64]:
    from grassd.calib.camera_response import cie_observer

    return cie_observer()[:, 1:2]


@lru_cache(maxsize=8)
def _recovered(lab_bytes: bytes) -> NDArray[np.float64]:
    lab = np.frombuffer(lab_bytes, dtype=np.float64).reshape(-1, 3)
    # the chart's CIELAB is under D50; Jakob-Hanika is fitted under D65 after Bradford
    return recover_reflectance(xyz_d50_to_d65(lab_to_xyz(lab)))


def chart_reflectances(chart: ReferenceChart | None = None) -> NDArray[np.float64]:
    """(24, n) reflectance spectra of a chart's patches on :data:`WAVELENGTHS`: None ->
    colour-science's measured ColorChecker spectra (:data:`~grassd.calib.camera_response.
    CHECKER_SPECTRA`); a :class:`~grassd.calib.charts.ReferenceChart` -> Jakob & Hanika's
    smooth spectra of its CIELAB values (about 0.1-0.5 s a patch the first time, cached)."""
    if chart is None:
        return checker_reflectances(CHECKER_SPECTRA)[1]
    lab = np.ascontiguousarray(chart.lab, dtype=np.float64)
    return _recovered(lab.tobytes()).copy()


Image = NDArray[np.float64]


def spectral_checker_scene(camera: SpectralVirtualCamera, white_nits: float = 80.0,
                           reflectances: ArrayLike | None = None, width: int = 384,
                           height: int = 256) -> tuple[Image, Image, Image]:
    """The sensor's own response (height, width, 3) to a checker lying at the display under
    the camera's light, its white card's response (3,), and the (4, 2) patch-area corners
    (TL, TR, BR, BL; pixels (x, y)), laid out as
    :func:`grassd.calib.checker_photo.checker_scene`; photograph it with
    :meth:`~grassd.calib.virtual_camera.VirtualCamera.photograph_camera_rgb`.

    ``white_nits``: the white card's luminance (scales everything); ``reflectances``: (24, n)
    patch spectra, default :func:`chart_reflectances` () (the measured ColorChecker). Every
    patch's response is the exact integral of its spectrum, never negative.
    """
    refl = chart_reflectances() if reflectances is None else np.asarray(reflectances,
                                                                          np.float64)
    if refl.shape != (24, len(WAVELENGTHS)) or (refl < 0).any():
        raise CameraResponseError(f"checker reflectances must be (24, {len(WAVELENGTHS)}) "
                                  f"non-negative spectra; got shape {refl.shape}")
    patches = camera.response_to_reflectance(refl) * white_nits
    white = camera.response_to_reflectance(np.ones(len(WAVELENGTHS))) * white_nits
    img, corners = checker_image(patches, CHART_BODY_ALBEDO * white, width, height)
    return img, white, corners
