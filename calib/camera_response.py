"""A camera defined by its spectral sensitivities: its raw RGB of reflectance spectra under a
light, and the map from the simulation's linear Rec.709 to that raw RGB.

A real sensor is not colorimetric: its three channels are not a linear combination of the CIE
1931 observer (the Luther condition fails), so no 3x3 (and no correction at all) maps every
spectrum's colour onto the camera's reading. Where the camera's sensitivities are known, the
simulation can instead predict the camera's *own* RGB and compare it with the photo's, with no
colour correction in between:

* :class:`CameraSensitivities`: ``S_c(lambda)`` (relative, any scale) on :data:`WAVELENGTHS`,
  from a CSV (:func:`read_sensitivities`, format below) or colour-science's measured cameras
  (:meth:`CameraSensitivities.from_colour`, National Physical Laboratory data);
* :meth:`CameraSensitivities.raw_rgb`: ``c = integral S_c E R d lambda`` of reflectances ``R``
  under a light ``E``, relative to the perfect white's brightest channel (trapezoids, nm);
* :meth:`CameraSensitivities.rec709_map`: the 3x3 ``T`` from the simulation's linear Rec.709 of
  each training reflectance under the light onto the camera's raw RGB of it, least squares over
  a spectral training set (by default colour-science's 24 ColorChecker spectra and a perfect
  white), with the leave-one-out error of each patch (:class:`CameraMap`). ``transport``
  says what the simulation's Rec.709 is: "rgb" (grassd's RGB renderer: the albedo's Rec.709
  under D65 times the light's Rec.709, channel by channel) or "spectral" (a spectral
  renderer's output: the CIE observer's Rec.709 of the reflected spectrum ``E R``);
* :func:`develop_camera_rgb`: raw RGB developed as LibRaw develops a DNG (white balance,
  ``rgb_cam`` from the profile as dcraw's ``cam_xyz_coeff`` makes it, sRGB -> ProPhoto), so a
  prediction and a photo are compared in the same CIELAB as :mod:`grassd.calib.ccm`;
* :func:`checker_experiment`: the checker photographed by such a camera under a light and the
  analytic virtual checker, the pairs a colour correction is fitted to;
* :func:`camera_correction`: the simulation's white-card-normalised ProPhoto -> the photo's
  developed ProPhoto, *predicted* from the sensitivities, the light's spectrum and the photo's
  own development (white balance, LibRaw's ``rgb_cam``) instead of fitted to the checker: a
  :class:`~grassd.calib.ccm.ColourCorrection` that goes wherever a fitted one goes.

CSV format of a camera's sensitivities (:func:`read_sensitivities`): UTF-8 text, one sample per
line ``wavelength_nm,r,g,b``; lines starting with ``#`` and blank lines are ignored, and the
first non-comment line may be the header ``wavelength_nm,r,g,b`` (any case). Wavelengths in nm,
strictly increasing, within 300..1100 nm, covering at least :data:`MIN_COVERAGE_NM`; values
finite and non-negative (a photodiode's response cannot be negative), any common scale, each
channel with a positive peak. Samples need not be evenly spaced: they are interpolated linearly
onto :data:`WAVELENGTHS`, zero outside the measured range.

References: R. Luther (1927), "Aus dem Gebiet der Farbreizmetrik", Z. techn. Physik 8;
G. Finlayson, M. Mackiewicz, A. Hurlbert (2015), "Color Correction Using Root-Polynomial
Regression", IEEE TIP 24(5); W. Jakob, J. Hanika (2019), "A Low-Dimensional Function Space for
Efficient Spectral Upsampling", Computer Graphics Forum 38(2); D. Coffin, dcraw.c
(``cam_xyz_coeff``); colour-science ``MSDS_CAMERA_SENSITIVITIES`` (NPL measurements) and
``SDS_COLOURCHECKERS`` (N. Ohta's ColorChecker spectra).
"""

from __future__ import annotations

import csv
from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike, NDArray

from grassd.calib.colour_spaces import (
    M_REC709_TO_PROPHOTO,
    M_REC709_TO_XYZ,
    M_XYZ_TO_PROPHOTO,
    M_XYZ_TO_REC709,
    WHITE_D50_XYZ,
)
from grassd.calib.errors import CameraResponseError, SensitivityFileError

if TYPE_CHECKING:
    from grassd.calib.ccm import ColourCorrection

#: Common wavelength grid of every spectrum here (nm): 380..780 in 5 nm steps.
WAVELENGTHS: NDArray[np.float64] = np.arange(380.0, 781.0, 5.0)
WAVELENGTHS.setflags(write=False)
#: The range (nm) a sensitivity table must cover at least: the whole of it carries most of the
#: CIE observer's weight (colour-science's Sigma SD Merrill data is measured over 400..680).
MIN_COVERAGE_NM: tuple[float, float] = (400.0, 680.0)
#: Cameras of colour-science's ``MSDS_CAMERA_SENSITIVITIES`` by a short name (the dataset
#: spells the Sigma "Merill").
COLOUR_CAMERAS: dict[str, str] = {
    "nikon-d5100": "Nikon 5100 (NPL)",
    "sigma-sdmerrill": "Sigma SDMerill (NPL)",
}
#: colour-science's 24 reflectance spectra of the ColorChecker (reading order), the default
#: training set.
CHECKER_SPECTRA: str = "ColorChecker N Ohta"
#: How the simulation's linear Rec.709 of a reflectance under a light is formed (module
#: docstring): "rgb" (grassd's renderer today) or "spectral".
TRANSPORTS: tuple[str, ...] = ("rgb", "spectral")


def resample(wavelengths: ArrayLike, values: ArrayLike) -> NDArray[np.float64]:
    """Tabulated spectra ``values`` (n,) or (n, k) at ``wavelengths`` (n,) nm, linearly
    interpolated onto :data:`WAVELENGTHS` and zero outside the tabulated range.

    >>> resample([400, 500], [1.0, 3.0])[[0, 4, 24, 30]].tolist()
    [0.0, 1.0, 3.0, 0.0]
    """
    wl = np.asarray(wavelengths, np.float64)
    v = np.asarray(values, np.float64)
    cols = v.reshape(len(wl), -1)
    out = np.stack([np.interp(WAVELENGTHS, wl, c, left=0.0, right=0.0) for c in cols.T], 1)
    return out[:, 0] if v.ndim == 1 else out


def _trapezoid() -> NDArray[np.float64]:
    w = np.full(len(WAVELENGTHS), WAVELENGTHS[1] - WAVELENGTHS[0])
    w[[0, -1]] *= 0.5
    return w


def integrate(spectra: ArrayLike, weights: ArrayLike) -> NDArray[np.float64]:
    """``integral spectra(lambda) weights_c(lambda) d lambda`` (nm) by trapezoids on
    :data:`WAVELENGTHS`: spectra (..., n) and weights (n, k) -> (..., k)."""
    return (np.asarray(spectra, np.float64) * _trapezoid()) @ np.asarray(weights, np.float64)


def cie_observer() -> NDArray[np.float64]:
    """CIE 1931 2 degree colour matching functions (n, 3) on :data:`WAVELENGTHS`."""
    import colour  # on first use: see grassd.calib.colour_spaces

    cmfs = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"]
    return resample(cmfs.wavelengths, cmfs.values)


def illuminant(light: str | ArrayLike) -> NDArray[np.float64]:
    """Relative spectral power (n,) on :data:`WAVELENGTHS` of ``light``: a name of
    colour-science's ``SDS_ILLUMINANTS`` ("D65", "A", "D50", "FL2", ...) or values (n,) already
    on the grid (finite, non-negative, not all zero).

    Raises:
        CameraResponseError: an unknown name, or values of the wrong length or sign.
    """
    if isinstance(light, str):
        import colour  # on first use: see grassd.calib.colour_spaces

        if light not in colour.SDS_ILLUMINANTS:
            raise CameraResponseError(f"unknown illuminant {light!r}; use a name of colour's "
                                      "SDS_ILLUMINANTS (D65, A, D50, FL2, ...) or a spectrum on "
                                      "380..780 nm in 5 nm steps")
        sd = colour.SDS_ILLUMINANTS[light]
        return resample(sd.wavelengths, sd.values)
    e = np.asarray(light, np.float64)
    if e.shape != WAVELENGTHS.shape or not np.isfinite(e).all() or (e < 0).any() or e.max() <= 0:
        raise CameraResponseError(f"an illuminant spectrum needs {len(WAVELENGTHS)} finite, "
                                  f"non-negative values on 380..780 nm (5 nm steps), not all 0; "
                                  f"got shape {e.shape}")
    return e


def checker_reflectances(dataset: str = CHECKER_SPECTRA
                         ) -> tuple[tuple[str, ...], NDArray[np.float64]]:
    """Names and (24, n) reflectance spectra (0..1) of a colour-science ``SDS_COLOURCHECKERS``
    dataset, reading order, on :data:`WAVELENGTHS`."""
    import colour  # on first use: see grassd.calib.colour_spaces

    if dataset not in colour.SDS_COLOURCHECKERS:
        raise CameraResponseError(f"unknown checker spectra {dataset!r}; use one of "
                                  f"{', '.join(colour.SDS_COLOURCHECKERS)}")
    sds = colour.SDS_COLOURCHECKERS[dataset]
    return tuple(sds), np.stack([resample(sd.wavelengths, sd.values) for sd in sds.values()])


def reflectance_xyz(reflectance: ArrayLike, light: str | ArrayLike) -> NDArray[np.float64]:
    """CIE XYZ (..., 3) of reflectances (..., n) under ``light``, Y of the perfect white 1."""
    e = illuminant(light)
    obs = cie_observer()
    return integrate(np.asarray(reflectance, np.float64) * e, obs) / integrate(e, obs)[1]


def simulation_rec709(reflectance: ArrayLike, light: str | ArrayLike,
                      transport: str = "rgb") -> NDArray[np.float64]:
    """The simulation's linear Rec.709 (..., 3) of reflectances (..., n) under ``light``,
    normalised to the perfect white's Y = 1 (module docstring).

    ``transport``: "rgb": the albedo (the reflectance's Rec.709 under D65, the perfect white's
    exactly (1, 1, 1)) times
    the light's Rec.709 (Y = 1), channel by channel, as grassd's RGB renderer forms it;
    "spectral": the Rec.709 of the CIE observer's XYZ of the reflected spectrum.
    """
    r = np.asarray(reflectance, np.float64)
    if transport == "spectral":
        return reflectance_xyz(r, light) @ M_XYZ_TO_REC709.T
    if transport == "rgb":
        ones = np.ones(len(WAVELENGTHS))
        albedo = reflectance_xyz(r, "D65") @ M_XYZ_TO_REC709.T
        albedo = albedo / (reflectance_xyz(ones, "D65") @ M_XYZ_TO_REC709.T)  # white: (1, 1, 1)
        return albedo * (reflectance_xyz(ones, light) @ M_XYZ_TO_REC709.T)
    raise CameraResponseError(f"unknown transport {transport!r}; use one of "
                              f"{', '.join(TRANSPORTS)}")


@dataclass(frozen=True, eq=False)
class CameraSensitivities:
    """A camera's relative spectral sensitivities.

    Attributes:
        name: what the camera is called (a file name or colour-science's key).
        values: (n, 3) sensitivities of R, G, B on :data:`WAVELENGTHS` (any common scale),
            zero outside the measured range.
        measured_nm: (first, last) wavelength of the measured range (nm).
    """

    name: str
    values: NDArray[np.float64]
    measured_nm: tuple[float, float]

    def __post_init__(self) -> None:
        v = np.asarray(self.values, np.float64)
        if v.shape != (len(WAVELENGTHS), 3) or not np.isfinite(v).all() or (v < 0).any():
            raise CameraResponseError(f"sensitivities of {self.name!r} must be ({len(WAVELENGTHS)},"
                                      f" 3) finite, non-negative values on WAVELENGTHS; got "
                                      f"shape {v.shape}")
        if (v.max(axis=0) <= 0).any():
            raise CameraResponseError(f"a channel of {self.name!r} has no positive sensitivity")

    @classmethod
    def from_colour(cls, name: str) -> CameraSensitivities:
        """A camera of colour-science's ``MSDS_CAMERA_SENSITIVITIES``, by a short name of
        :data:`COLOUR_CAMERAS` or the dataset's own key."""
        import colour  # on first use: see grassd.calib.colour_spaces

        key = COLOUR_CAMERAS.get(name, name)
        if key not in colour.characterisation.MSDS_CAMERA_SENSITIVITIES:
            raise CameraResponseError(f"unknown camera {name!r}; use one of "
                                      f"{', '.join(COLOUR_CAMERAS)} or a CSV of sensitivities")
        m = colour.characterisation.MSDS_CAMERA_SENSITIVITIES[key]
        wl = np.asarray(m.wavelengths, np.float64)
        return cls(key, resample(wl, m.values), (float(wl[0]), float(wl[-1])))

    def response(self, radiance: ArrayLike) -> NDArray[np.float64]:
        """Raw RGB (..., 3) of spectral radiances (..., n) on :data:`WAVELENGTHS`:
        ``integral S_c L d lambda`` (units of the radiance times nm times S)."""
        return integrate(radiance, self.values)

    def raw_rgb(self, reflectance: ArrayLike, light: str | ArrayLike) -> NDArray[np.float64]:
        """Raw RGB (..., 3) of reflectances (..., n) under ``light``, relative to the perfect
        white's brightest channel (module docstring)."""
        e = illuminant(light)
        return self.response(np.asarray(reflectance, np.float64) * e) / self.white(e).max()

    def white(self, light: str | ArrayLike) -> NDArray[np.float64]:
        """Raw RGB (3,) of a perfect white under ``light`` (unnormalised)."""
        return self.response(illuminant(light))

    @cached_property
    def xyz_to_camera(self) -> NDArray[np.float64]:
        """(3, 3) DNG ColorMatrix1 as a maker would make it: the least-squares map of
        D65-relative XYZ (white Y = 1) onto the camera's raw RGB over the ColorChecker spectra
        and a perfect white under D65, scaled so the white's brightest channel is 1."""
        _, refl = checker_reflectances()
        refl = np.vstack([refl, np.ones(len(WAVELENGTHS))])
        xyz = reflectance_xyz(refl, "D65")
        cam = self.raw_rgb(refl, "D65")
        m, *_ = np.linalg.lstsq(xyz, cam, rcond=None)
        return m.T / float((m.T @ xyz[-1]).max())

    def rec709_map(self, light: str | ArrayLike, training: ArrayLike | None = None,
                   transport: str = "rgb") -> CameraMap:
        """The 3x3 from the simulation's linear Rec.709 (:func:`simulation_rec709`) onto this
        camera's raw RGB (:meth:`raw_rgb`) under ``light``, fitted by least squares over the
        ``training`` reflectances (m, n) (default: :data:`CHECKER_SPECTRA` and a perfect
        white), with each training sample's leave-one-out prediction (closed form, as
        :func:`grassd.calib.ccm.leave_one_out_rgb`). The fit, and so the prediction, is the
        same whatever linear development the raw RGB is then compared in (each developed
        channel is a linear combination of the raw ones).

        Raises:
            CameraResponseError: fewer than 4 training spectra, or an unknown transport.
        """
        if training is None:
            training = np.vstack([checker_reflectances()[1], np.ones(len(WAVELENGTHS))])
        t = np.asarray(training, np.float64)
        if t.ndim != 2 or t.shape[1] != len(WAVELENGTHS) or t.shape[0] < 4:
            raise CameraResponseError(f"training reflectances must be (m >= 4, "
                                      f"{len(WAVELENGTHS)}); got shape {t.shape}")
        x = simulation_rec709(t, light, transport)
        y = self.raw_rgb(t, light)
        m, *_ = np.linalg.lstsq(x, y, rcond=None)
        u, _, _ = np.linalg.svd(x, full_matrices=False)
        lev = np.einsum("ij,ij->i", u, u)
        loo = y - (y - x @ m) / (1.0 - lev)[:, None]
        return CameraMap(matrix=m.T, transport=transport, rec709=x, camera=y, loo_camera=loo)


@dataclass(frozen=True, eq=False)
class CameraMap:
    """The simulation's linear Rec.709 -> a camera's raw RGB, fitted over training spectra.

    Attributes:
        matrix: (3, 3) ``camera = matrix @ rec709``.
        transport: how the training Rec.709 was formed ("rgb" or "spectral").
        rec709: (m, 3) the training samples' simulated Rec.709.
        camera: (m, 3) their true raw RGB.
        loo_camera: (m, 3) each sample's raw RGB predicted by the map fitted to the others.
    """

    matrix: NDArray[np.float64]
    transport: str
    rec709: NDArray[np.float64]
    camera: NDArray[np.float64]
    loo_camera: NDArray[np.float64]

    def apply(self, rec709: ArrayLike) -> NDArray[np.float64]:
        """Predicted raw RGB (..., 3) of the simulation's linear Rec.709 (..., 3)."""
        return np.asarray(rec709, np.float64) @ self.matrix.T


def read_sensitivities(path: str | Path) -> CameraSensitivities:
    """Read a camera's spectral sensitivities from a CSV (format in the module docstring).

    Raises:
        SensitivityFileError: missing or unreadable file, a malformed line (named by number),
            wavelengths not increasing or outside 300..1100 nm or not covering
            :data:`MIN_COVERAGE_NM`, negative or non-finite values, a channel all zero.
    """
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise SensitivityFileError(f"cannot read the sensitivities file {p} ({exc}); give a "
                                   "UTF-8 CSV of wavelength_nm,r,g,b") from None
    rows: list[list[float]] = []
    for lineno, row in enumerate(csv.reader(text.splitlines()), start=1):
        cells = [c.strip() for c in row]
        if not cells or not "".join(cells) or cells[0].startswith("#"):
            continue
        if not rows and [c.lower() for c in cells] == ["wavelength_nm", "r", "g", "b"]:
            continue
        if len(cells) != 4:
            raise SensitivityFileError(f"{p.name} line {lineno}: {len(cells)} fields; each line "
                                       "is wavelength_nm,r,g,b")
        try:
            rows.append([float(c) for c in cells])
        except ValueError:
            raise SensitivityFileError(f"{p.name} line {lineno}: {row!r} is not four numbers "
                                       "(wavelength_nm,r,g,b)") from None
    if len(rows) < 2:
        raise SensitivityFileError(f"{p.name}: {len(rows)} samples; a sensitivity table needs "
                                   f"samples across {MIN_COVERAGE_NM[0]:g}..{MIN_COVERAGE_NM[1]:g}"
                                   " nm")
    a = np.asarray(rows, np.float64)
    wl, v = a[:, 0], a[:, 1:]
    if not np.isfinite(a).all():
        raise SensitivityFileError(f"{p.name}: non-finite values (nan/inf); give measured numbers")
    if (np.diff(wl) <= 0).any():
        i = int(np.flatnonzero(np.diff(wl) <= 0)[0])
        raise SensitivityFileError(f"{p.name}: wavelengths must increase strictly; {wl[i]:g} nm "
                                   f"is followed by {wl[i + 1]:g} nm")
    if wl[0] < 300 or wl[-1] > 1100:
        raise SensitivityFileError(f"{p.name}: wavelengths {wl[0]:g}..{wl[-1]:g} nm; give them in "
                                   "nm (300..1100), not um or m")
    if wl[0] > MIN_COVERAGE_NM[0] or wl[-1] < MIN_COVERAGE_NM[1]:
        raise SensitivityFileError(f"{p.name}: measured over {wl[0]:g}..{wl[-1]:g} nm; the table "
                                   f"must cover at least {MIN_COVERAGE_NM[0]:g}.."
                                   f"{MIN_COVERAGE_NM[1]:g} nm")
    if (v < 0).any():
        i = int(np.flatnonzero((v < 0).any(axis=1))[0])
        raise SensitivityFileError(f"{p.name}: negative sensitivity at {wl[i]:g} nm; a "
                                   "photodiode's response is never negative (a fitted or "
                                   "matrixed table? give the measured one)")
    if (v.max(axis=0) <= 0).any():
        ch = "rgb"[int(np.flatnonzero(v.max(axis=0) <= 0)[0])]
        raise SensitivityFileError(f"{p.name}: channel {ch} is zero at every wavelength")
    return CameraSensitivities(p.stem, resample(wl, v), (float(wl[0]), float(wl[-1])))


def write_sensitivities(path: str | Path, camera: CameraSensitivities,
                        comment: str | None = None) -> Path:
    """Write ``camera``'s sensitivities over its measured range as a CSV that
    :func:`read_sensitivities` reads back."""
    p = Path(path)
    keep = (WAVELENGTHS >= camera.measured_nm[0]) & (WAVELENGTHS <= camera.measured_nm[1])
    lines = [f"# {comment or camera.name}", "wavelength_nm,r,g,b"]
    lines += [f"{w:g},{r:.8g},{g:.8g},{b:.8g}"
              for w, (r, g, b) in zip(WAVELENGTHS[keep], camera.values[keep], strict=True)]
    p.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return p


# ------------------------------------------------------------------ development and the checker
#: Rec.709 -> XYZ of sRGB (D65): what dcraw's ``cam_xyz_coeff`` multiplies the profile by.
_SRGB_TO_XYZ = M_REC709_TO_XYZ


def rgb_cam(xyz_to_camera: ArrayLike) -> NDArray[np.float64]:
    """(3, 3) camera -> linear sRGB as LibRaw builds it from a DNG ColorMatrix (dcraw's
    ``cam_xyz_coeff``): ``cam_rgb = xyz_to_camera @ srgb_to_xyz``, rows normalised to sum 1,
    inverted."""
    cam_rgb = np.asarray(xyz_to_camera, np.float64) @ _SRGB_TO_XYZ
    cam_rgb = cam_rgb / cam_rgb.sum(axis=1, keepdims=True)
    return np.linalg.inv(cam_rgb)


def develop_camera_rgb(raw: ArrayLike, xyz_to_camera: ArrayLike,
                       multipliers: ArrayLike) -> NDArray[np.float64]:
    """ProPhoto linear RGB (..., 3) of raw RGB (..., 3) developed as LibRaw develops a DNG with
    that profile and white-balance ``multipliers`` (3,): ``rec709_to_prophoto(rgb_cam @ (wb *
    raw))`` (no clipping)."""
    srgb = (np.asarray(raw, np.float64) * np.asarray(multipliers, np.float64)) @ rgb_cam(
        xyz_to_camera).T
    return srgb @ M_REC709_TO_PROPHOTO.T


def grey_multipliers(grey_raw: ArrayLike, grey_prophoto: ArrayLike,
                     xyz_to_camera: ArrayLike) -> NDArray[np.float64]:
    """White-balance multipliers (3,) that develop the raw RGB of the checker's grey patch to
    the chromaticity of its reference (as :func:`grassd.calib.checker_photo.checker_white_balance`
    does on a photo), green = 1."""
    target = np.linalg.solve(rgb_cam(xyz_to_camera),
                             np.asarray(grey_prophoto, np.float64) @ np.linalg.inv(
                                 M_REC709_TO_PROPHOTO).T)
    wb = target / np.asarray(grey_raw, np.float64)
    return wb / wb[1]


@dataclass(frozen=True, eq=False)
class CheckerExperiment:
    """A checker photographed by a spectral camera under a light, and its virtual twin.

    Attributes:
        names: the patch names.
        virtual: (24, 3) ProPhoto linear albedo of the patches (their spectra under D50, white
            Y = 1), the analytic virtual checker's side of a colour correction.
        real: (24, 3) the photo's patches developed (white balance on the grey, the camera's
            profile), grey scaled to the virtual grey's Y: the real side.
        raw: (24, 3) the patches' raw RGB (white's brightest channel 1).
        multipliers: (3,) the white balance used.
        scale: the factor that put the developed grey at the virtual grey's Y.
        grey: index of the grey patch used.
    """

    names: tuple[str, ...]
    virtual: NDArray[np.float64]
    real: NDArray[np.float64]
    raw: NDArray[np.float64]
    multipliers: NDArray[np.float64]
    scale: float
    grey: int

    def develop(self, raw: ArrayLike, camera: CameraSensitivities) -> NDArray[np.float64]:
        """Raw RGB (..., 3) developed exactly as the photo's patches were (same white balance,
        profile and scale): a prediction of the camera's raw RGB becomes comparable with
        :attr:`real`."""
        return develop_camera_rgb(raw, camera.xyz_to_camera, self.multipliers) * self.scale

    def development(self, camera: CameraSensitivities) -> NDArray[np.float64]:
        """(3, 3) the linear map :meth:`develop` applies: raw RGB -> ProPhoto linear."""
        return self.develop(np.eye(3), camera).T


def checker_experiment(camera: CameraSensitivities, light: str | ArrayLike,
                       dataset: str = CHECKER_SPECTRA, grey: int | None = None
                       ) -> CheckerExperiment:
    """The checker of ``dataset`` photographed by ``camera`` under ``light`` and developed as
    ``grassd`` develops a checker photo (white balance from the grey patch, the camera's
    profile :attr:`CameraSensitivities.xyz_to_camera`, grey at the virtual grey's Y), beside
    the analytic virtual checker (module docstring). ``grey``: the grey patch's index (default:
    the neutral patch nearest L* 50)."""
    names, refl = checker_reflectances(dataset)
    xyz_d50 = reflectance_xyz(refl, "D50")
    virtual = xyz_d50 @ M_XYZ_TO_PROPHOTO.T * (1.0 / float(WHITE_D50_XYZ[1]))
    if grey is None:
        import colour  # on first use: see grassd.calib.colour_spaces

        lab = colour.XYZ_to_Lab(xyz_d50, colour.XYZ_to_xy(WHITE_D50_XYZ))
        chroma = np.hypot(lab[:, 1], lab[:, 2])
        grey = int(np.argmin(np.abs(lab[:, 0] - 50.0) + np.where(chroma > 5.0, 1e3, 0.0)))
    raw = camera.raw_rgb(refl, light)
    wb = grey_multipliers(raw[grey], virtual[grey], camera.xyz_to_camera)
    dev = develop_camera_rgb(raw, camera.xyz_to_camera, wb)
    scale = float((virtual[grey] @ _Y_OF_PROPHOTO) / (dev[grey] @ _Y_OF_PROPHOTO))
    return CheckerExperiment(names, virtual, dev * scale, raw, wb, scale, grey)


#: Y of ProPhoto linear RGB (the second row of ProPhoto -> XYZ).
_Y_OF_PROPHOTO: NDArray[np.float64] = np.linalg.inv(M_XYZ_TO_PROPHOTO)[1]


def camera_route_de00(camera: CameraSensitivities, light: str | ArrayLike,
                      transport: str = "rgb", dataset: str = CHECKER_SPECTRA
                      ) -> NDArray[np.float64]:
    """(24,) CIEDE2000 between each checker patch as photographed (:func:`checker_experiment`)
    and the simulation's prediction of the camera's own raw RGB of it, through the
    :meth:`CameraSensitivities.rec709_map` fitted over the *other* patches (and the white),
    developed the same way: the comparison that needs no colour correction, leave-one-out."""
    from grassd.calib.ccm import residual_de00

    exp = checker_experiment(camera, light, dataset)
    _, refl = checker_reflectances(dataset)
    training = np.vstack([refl, np.ones(len(WAVELENGTHS))])
    cmap = camera.rec709_map(light, training, transport)
    pred = exp.develop(cmap.loo_camera[:-1], camera)
    return residual_de00(np.clip(pred, 0.0, None), np.clip(exp.real, 0.0, None))


def upsampled_route_de00(camera: CameraSensitivities, light: str | ArrayLike,
                         dataset: str = CHECKER_SPECTRA) -> NDArray[np.float64]:
    """(24,) CIEDE2000 between each checker patch as photographed and a spectral simulation's
    prediction that knows only the patch's colour: its reflectance recovered from its XYZ under
    D65 (Jakob & Hanika 2019, colour-science's ``XYZ_to_sd``), then integrated against the
    camera's sensitivities under ``light``, developed the same way (no fit, no correction)."""

    from grassd.calib.ccm import residual_de00

    exp = checker_experiment(camera, light, dataset)
    _, refl = checker_reflectances(dataset)
    xyz = reflectance_xyz(refl, "D65")
    up = recover_reflectance(xyz)
    pred = exp.develop(camera.raw_rgb(up, light), camera)
    return residual_de00(np.clip(pred, 0.0, None), np.clip(exp.real, 0.0, None))


def recover_reflectance(xyz_d65: ArrayLike) -> NDArray[np.float64]:
    """Smooth reflectance spectra (m, n) on :data:`WAVELENGTHS`, bounded to 0..1, whose colour
    under D65 is ``xyz_d65`` (m, 3) (white Y = 1): Jakob & Hanika's (2019) sigmoid-polynomial
    spectra, fitted per colour by colour-science's ``XYZ_to_sd(method="Jakob 2019")`` (about
    0.1 s a colour)."""
    import colour  # on first use: see grassd.calib.colour_spaces

    d65 = colour.SDS_ILLUMINANTS["D65"]
    out = []
    for x in np.atleast_2d(np.asarray(xyz_d65, np.float64)):
        sd = colour.XYZ_to_sd(x, method="Jakob 2019", illuminant=d65)
        out.append(resample(sd.wavelengths, sd.values))
    return np.stack(out)


def ccm_forms_on_checker(camera: CameraSensitivities, light: str | ArrayLike,
                         forms: Sequence[str] | None = None, dataset: str = CHECKER_SPECTRA
                         ) -> dict[str, ColourCorrection]:
    """{form: ColourCorrection} of every colour-correction form (:data:`grassd.calib.ccm.
    CCM_FORMS`) fitted from the virtual to the photographed checker of
    :func:`checker_experiment`, each with its leave-one-out errors."""
    from grassd.calib.ccm import CCM_FORMS, compare_ccm_forms

    exp = checker_experiment(camera, light, dataset)
    return compare_ccm_forms(exp.virtual, np.clip(exp.real, 0.0, None),
                             tuple(forms or CCM_FORMS))


def camera_correction(camera: CameraSensitivities, light: str | ArrayLike,
                      multipliers: ArrayLike, rgb_cam_matrix: ArrayLike,
                      grey_prophoto: ArrayLike, transport: str = "rgb",
                      training: ArrayLike | None = None) -> ColourCorrection:
    """The 3x3 from the simulation's ProPhoto (normalised by the white card channel by channel,
    as grassd's renders are) onto a photo's developed ProPhoto, predicted from the camera's
    sensitivities instead of fitted to the checker.

    The chain, each step linear: ProPhoto -> Rec.709, times the light's Rec.709 (the radiance
    the simulation rendered), the :meth:`CameraSensitivities.rec709_map` of ``transport`` onto
    raw RGB, the photo's white-balance ``multipliers`` (R, G, B[, G2]), LibRaw's ``rgb_cam`` of
    the photo (``rgb_cam_matrix``, :func:`grassd.calib.checker_photo.raw_rgb_cam`), sRGB ->
    ProPhoto; then scaled so the chart's grey (``grey_prophoto``, its white-card-normalised
    ProPhoto) keeps its luminance. Fold the virtual checker's scale in with
    :meth:`~grassd.calib.ccm.ColourCorrection.scaled` as for a fitted correction.

    Returns:
        A "3x3" ColourCorrection with no residuals (NaN; nothing was fitted): evaluate it on
        the photo's patches with :func:`grassd.calib.ccm.residual_de00`.
    """
    from grassd.calib.ccm import ColourCorrection

    cmap = camera.rec709_map(light, training, transport)
    w = simulation_rec709(np.ones(len(WAVELENGTHS)), light, transport)
    wb = np.asarray(multipliers, np.float64).ravel()[:3]
    rc = np.asarray(rgb_cam_matrix, np.float64)[:3, :3]
    if wb.shape != (3,) or not np.isfinite(wb).all() or (wb <= 0).any():
        raise CameraResponseError(f"white-balance multipliers must be 3 or 4 positive numbers; "
                                  f"got {np.asarray(multipliers).tolist()}")
    if not np.isfinite(rc).all() or abs(np.linalg.det(rc)) < 1e-12:
        raise CameraResponseError(f"rgb_cam must be LibRaw's invertible camera -> sRGB matrix; "
                                  f"got {rc.tolist()}")
    m = (M_REC709_TO_PROPHOTO @ rc @ np.diag(wb) @ cmap.matrix @ np.diag(w)
         @ np.linalg.inv(M_REC709_TO_PROPHOTO))
    g = np.asarray(grey_prophoto, np.float64)
    m = m * float((g @ _Y_OF_PROPHOTO) / ((m @ g) @ _Y_OF_PROPHOTO))
    nan = float("nan")
    return ColourCorrection("3x3", m, 1, np.zeros(0), nan, nan)
