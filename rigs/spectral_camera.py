"""A camera defined by its spectral sensitivities, for the spectral world (:mod:`.spectral_world`).

A real sensor is not colorimetric: its three channels are not a linear combination of the CIE
observer (the Luther condition fails), so no 3x3 matrix maps its raw RGB onto XYZ for every
spectrum. grassd's own virtual camera (:class:`grassd.calib.virtual_camera.VirtualCamera`) is
a 3x3 of XYZ and cannot show that; this one integrates the radiance *spectrum* against measured
sensitivities, so the error a real camera adds reaches grassd's chain.

The model:

1. Response: channel ``c`` of a photosite sees ``integral S_c(lambda) L(lambda) d lambda`` (nm)
   of the spectral radiance ``L``; Mitsuba's ``specfilm`` computes exactly that integral with
   the channels this module hands it (:meth:`SpectralCamera.film_channels`), and
   :meth:`SpectralCamera.response` computes it for tabulated spectra (trapezoids on
   :data:`WAVELENGTHS`). ``S_c`` are colour-science's measured sensitivities
   (``colour.characterisation.MSDS_CAMERA_SENSITIVITIES``, National Physical Laboratory, each
   channel peaking at 1), resampled linearly onto :data:`WAVELENGTHS` and zero outside their
   measured range. The Sigma SD Merrill is a Foveon (stacked) sensor; here it is mosaicked
   like the others, which changes its noise, not its colour.
2. The profile written into the DNG (ColorMatrix1, XYZ -> camera under D65), as a maker or
   Adobe would make it: the least-squares 3x3 over the 24 ColorChecker spectra (N. Ohta's
   measurements in colour-science) and a perfect white under CIE D65, scaled so the D65
   white's largest channel is 1 (:meth:`SpectralCamera.xyz_to_camera`).
3. Everything after the response, as :class:`grassd.calib.virtual_camera.VirtualCamera` does
   it: exposure fixed by a white card, lens blur, the Bayer mosaic, Poisson shot noise, Gaussian
   read noise, a 14-bit ADC and a DNG. It is handed the camera RGB already integrated, with a
   response matrix that makes its own colour step the identity
   (:meth:`SpectralCamera.virtual_camera`).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from grassd.calib.colour_spaces import M_REC709_TO_XYZ
from grassd.calib.virtual_camera import VirtualCamera

#: Common wavelength grid of every spectrum here (nm): 380..780 in 5 nm steps.
WAVELENGTHS: NDArray[np.float64] = np.arange(380.0, 781.0, 5.0)
#: Camera name -> colour-science dataset key (MSDS_CAMERA_SENSITIVITIES; "Merill" is its
#: spelling).
CAMERAS: dict[str, str] = {
    "nikon-d5100": "Nikon 5100 (NPL)",
    "sigma-sdmerrill": "Sigma SDMerill (NPL)",
    "cie-1931": "CIE 1931 2 Degree Standard Observer",
}
#: The camera whose sensitivities are the CIE observer's (each channel peaking at 1): a
#: colorimetric sensor, for telling a real sensor's error from the rest of a chain's.
COLORIMETRIC = "cie-1931"
#: colour-science's 24 reflectance spectra of the chart (reading order) used for the profile.
CHECKER_SPECTRA = "ColorChecker N Ohta"


class SpectralCameraError(ValueError):
    """A camera or spectrum this module cannot use; the message says what to change."""


def resample(wavelengths: ArrayLike, values: ArrayLike) -> NDArray[np.float64]:
    """Tabulated spectra ``values`` (n,) or (n, k) at ``wavelengths`` (n,) nm, linearly
    interpolated onto :data:`WAVELENGTHS` and zero outside the tabulated range."""
    wl = np.asarray(wavelengths, np.float64)
    v = np.asarray(values, np.float64)
    cols = v.reshape(len(wl), -1)
    out = np.stack([np.interp(WAVELENGTHS, wl, c, left=0.0, right=0.0) for c in cols.T], 1)
    return out[:, 0] if v.ndim == 1 else out


def integrate(spectra: ArrayLike, weights: ArrayLike) -> NDArray[np.float64]:
    """``integral spectra(lambda) weights_c(lambda) d lambda`` (nm) by trapezoids on
    :data:`WAVELENGTHS`: spectra (..., n) and weights (n, k) -> (..., k)."""
    s = np.asarray(spectra, np.float64)
    w = np.asarray(weights, np.float64)
    trap = np.full(len(WAVELENGTHS), WAVELENGTHS[1] - WAVELENGTHS[0])
    trap[[0, -1]] *= 0.5
    return (s * trap) @ w


def cie_observer() -> NDArray[np.float64]:
    """CIE 1931 2 degree colour matching functions (n, 3) on :data:`WAVELENGTHS`."""
    import colour

    cmfs = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"]
    return resample(cmfs.wavelengths, cmfs.values)


def d65() -> NDArray[np.float64]:
    """CIE D65 relative spectral power (n,) on :data:`WAVELENGTHS` (100 at 560 nm)."""
    import colour

    sd = colour.SDS_ILLUMINANTS["D65"]
    return resample(sd.wavelengths, sd.values)


def checker_reflectances() -> tuple[tuple[str, ...], NDArray[np.float64]]:
    """Names and (24, n) reflectance spectra of :data:`CHECKER_SPECTRA`, reading order."""
    import colour

    sds = colour.SDS_COLOURCHECKERS[CHECKER_SPECTRA]
    names = tuple(sds)
    return names, np.stack([resample(sd.wavelengths, sd.values) for sd in sds.values()])


def irregular_spectrum(values: ArrayLike) -> dict:
    """Mitsuba ``irregular`` spectrum plugin dict of a spectrum (n,) on :data:`WAVELENGTHS`."""
    v = np.asarray(values, np.float64)
    if v.shape != WAVELENGTHS.shape or not np.isfinite(v).all():
        raise SpectralCameraError(f"a spectrum needs {len(WAVELENGTHS)} finite values on "
                                  f"380..780 nm; got shape {v.shape}")
    return {"type": "irregular", "wavelengths": ",".join(f"{w:g}" for w in WAVELENGTHS),
            "values": ",".join(f"{x:.8g}" for x in v)}


@dataclass(frozen=True)
class SpectralCamera:
    """A camera: measured spectral sensitivities plus the sensor of a VirtualCamera.

    Attributes:
        name: a key of :data:`CAMERAS`.
        cfa_pattern, bits, full_well_e, read_noise_e, white_fraction, blur_px: as
            :class:`grassd.calib.virtual_camera.VirtualCamera` (ADC bits, electrons at white
            level, read noise in electrons, the white card's share of full scale in its
            brightest channel, lens blur in pixels).
    """

    name: str = "nikon-d5100"
    cfa_pattern: str = "RGGB"
    bits: int = 14
    full_well_e: float = 30000.0
    read_noise_e: float = 3.0
    white_fraction: float = 0.6
    blur_px: float = 1.0

    def __post_init__(self) -> None:
        if self.name not in CAMERAS:
            raise SpectralCameraError(f"unknown camera {self.name!r}; use one of "
                                      f"{', '.join(CAMERAS)}")

    @cached_property
    def sensitivities(self) -> NDArray[np.float64]:
        """(n, 3) relative spectral sensitivities of R, G, B on :data:`WAVELENGTHS`."""
        import colour

        if self.name == COLORIMETRIC:
            cmf = cie_observer()
            return cmf / cmf.max(axis=0)
        msds = colour.characterisation.MSDS_CAMERA_SENSITIVITIES[CAMERAS[self.name]]
        return resample(msds.wavelengths, msds.values)

    def film_channels(self, prefix: str) -> dict[str, dict]:
        """Mitsuba ``specfilm`` channels ``{prefix}r``, ``{prefix}g``, ``{prefix}b``: the film
        then stores ``integral S_c L d lambda`` per pixel (radiance in Mitsuba's units)."""
        return {f"{prefix}{c}": irregular_spectrum(self.sensitivities[:, i])
                for i, c in enumerate("rgb")}

    def response(self, spectra: ArrayLike) -> NDArray[np.float64]:
        """Raw RGB (..., 3) of spectral radiances (..., n) on :data:`WAVELENGTHS`, in the units
        of the radiance times nm."""
        return integrate(spectra, self.sensitivities)

    @cached_property
    def xyz_to_camera(self) -> NDArray[np.float64]:
        """(3, 3) DNG ColorMatrix1: the least-squares map of D65-relative XYZ (Y of white 1)
        onto the camera's response, over the checker spectra and a perfect white under D65,
        scaled so the D65 white's brightest channel is 1 (module docstring, step 2)."""
        _, refl = checker_reflectances()
        refl = np.vstack([refl, np.ones(len(WAVELENGTHS))])
        light = refl * d65()
        norm = float(integrate(d65(), cie_observer()[:, 1:2])[0])
        xyz = integrate(light, cie_observer()) / norm
        cam = self.response(light) / norm
        m, *_ = np.linalg.lstsq(xyz, cam, rcond=None)
        c = m.T
        return c / float((c @ xyz[-1]).max())

    def luther_residual(self) -> float:
        """RMS error of the profile over the 24 checker spectra under D65, relative to the D65
        white's brightest channel: 0 for a colorimetric camera (the Luther condition)."""
        _, refl = checker_reflectances()
        light = np.vstack([refl, np.ones(len(WAVELENGTHS))]) * d65()
        xyz = integrate(light, cie_observer())
        xyz = xyz / xyz[-1, 1]
        cam = self.response(light)
        cam = cam / cam[-1].max()
        return float(np.sqrt(np.mean((xyz[:-1] @ self.xyz_to_camera.T - cam[:-1]) ** 2)))

    def virtual_camera(self) -> VirtualCamera:
        """The sensor after the response: a VirtualCamera whose colour step is the identity
        (its XYZ -> camera matrix is the inverse of Rec.709 -> XYZ, so it passes the RGB it is
        handed through) and whose DNG carries :attr:`xyz_to_camera` as the profile."""
        return VirtualCamera(xyz_to_camera=np.linalg.inv(M_REC709_TO_XYZ),
                             profile=self.xyz_to_camera, cfa_pattern=self.cfa_pattern,
                             bits=self.bits, full_well_e=self.full_well_e,
                             read_noise_e=self.read_noise_e, white_fraction=self.white_fraction,
                             blur_px=self.blur_px, make="grassd spectral",
                             model=CAMERAS[self.name])

    def exposure_for(self, white_rgb: ArrayLike) -> float:
        """Electrons per unit response so a white card whose raw RGB is ``white_rgb`` (3,)
        fills :attr:`white_fraction` of the full well in its brightest channel."""
        return self.virtual_camera().exposure_for(np.asarray(white_rgb, np.float64))

    def photograph(self, path: str | Path, raw_rgb: ArrayLike, white_rgb: ArrayLike,
                   electrons_per_unit: float, seed: int) -> Path:
        """Write the DNG of a raw RGB image (H, W, 3; even H, W) as this camera's response:
        blur, Bayer, shot and read noise, ADC; AsShotNeutral is the white card's RGB."""
        rgb = np.asarray(raw_rgb, np.float64)
        if rgb.ndim != 3 or rgb.shape[2] != 3 or (rgb < 0).any() or not np.isfinite(rgb).all():
            raise SpectralCameraError(f"raw RGB must be a finite non-negative (H, W, 3) image; "
                                      f"got {rgb.shape}")
        return self.virtual_camera().photograph(path, rgb, np.asarray(white_rgb, np.float64),
                                                electrons_per_unit=electrons_per_unit,
                                                seed=seed)
