"""A camera's developed colour of a simulated pixel, predicted through spectra: no correction.

grassd renders in linear Rec.709 and reads its renders through the CIE observer; a real camera
departs from that observer (the Luther condition), so a colour correction fitted to a checker
leaves a floor (``docs/calib/colour_chain.md``). Where the camera's spectral sensitivities are
known, this module predicts the camera's own raw RGB of a simulated pixel instead, developed as
its photo is developed, so the comparison with the photo needs no correction at all:

* **Materials as spectra.** Each albedo (linear Rec.709) becomes the smooth reflectance of
  Jakob and Hanika (2019, "A Low-Dimensional Function Space for Efficient Spectral Upsampling",
  Computer Graphics Forum 38(2)): ``rho(lambda) = s(c0 t^2 + c1 t + c2)``, ``t`` the wavelength
  scaled to 0..1 over :data:`WAVELENGTHS`, ``s(x) = 1/2 + x / (2 sqrt(1 + x^2))``, with the
  three coefficients solved (:func:`sigmoid_spectra`, vectorised Newton) so that the spectrum's
  linear Rec.709 under D65 is the albedo exactly. The family is that of colour-science's
  ``XYZ_to_sd(method="Jakob 2019")`` and Mitsuba's spectral upsampling; a solve costs
  microseconds, not the 0.03-0.1 s of colour's, so a fit can call it in its inner loop.
* **Light as spectra.** Each texel of the light's map is upsampled as Mitsuba's spectral
  variants upsample an emitter's colour (:func:`emitter_spectra`: the smooth reflectance of
  the colour at half its largest channel, times D65). The albedo polynomial's coefficients
  are recorded per Rec.709 channel of the light (:mod:`grassd.sim.albedo_terms`), so the
  light enters as a linear basis, three spectra whose mix a light's colour is: the one
  closest to the map's own texels that gives a white card exactly their spectrum
  (:func:`fitted_light_basis`); :func:`light_basis` (D65 times Mallett and Yuksel's 2019
  basis) where nothing is known of the light.
* **Transport per wavelength.** A monomial of the polynomial is a product of reflectances, so
  evaluated on the materials' spectra it is a spectrum; :func:`transfer` integrates each
  monomial times each light basis spectrum against the camera's sensitivities (or the CIE
  observer): the pixel's raw RGB is ``sum_mk coefficient_mk * T_mkc``. Paths of a Lambertian
  pixel do not depend on the albedos, so this is spectral transport of the recorded paths,
  exact up to the quadrature (5 nm trapezoids) and the tail term beyond the polynomial's degree
  (its further vertices keep the reference's Rec.709 reflectance per channel).
* **Development.** :class:`Development` applies a photo's white-balance multipliers and
  LibRaw's ``rgb_cam`` (from the photo's own profile), converts to ProPhoto, and scales so the
  checker's grey, a flat spectrum of its reference luminance under the same light, reads the
  exposure's ``Y = 0.18`` as :func:`grassd.daemon.offline.validate.measure_real` scales the
  photos.

Units: wavelengths nm; reflectances and albedos 0..1; radiances relative (any common scale;
the development normalises by the white card).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from grassd.calib.camera_response import (
    WAVELENGTHS,
    cie_observer,
    illuminant,
    integrate,
    rgb_cam,
)
from grassd.calib.colour_spaces import (
    M_REC709_TO_PROPHOTO,
    M_XYZ_TO_REC709,
    luminance,
)
from grassd.calib.errors import CalibError
from grassd.calib.exposure import GREY_CARD_Y

#: Newton steps :func:`sigmoid_spectra` takes at most (it converges in 5-15 from grey).
MAX_NEWTON_STEPS: int = 60
#: Largest Rec.709 residual (0..1) :func:`sigmoid_spectra` accepts as a match.
MATCH_TOLERANCE: float = 1e-9
#: Albedos are held this far inside 0..1: a sigmoid reaches 0 and 1 only in the limit.
EDGE: float = 1e-4


class SpectralPredictionError(CalibError):
    """A colour cannot be turned into a spectrum, or a development cannot be predicted; the
    message says which and how to fix it."""


#: The wavelength's powers (t^2, t, 1) of the sigmoid's polynomial, t = 0..1 over WAVELENGTHS.
_T = (WAVELENGTHS - WAVELENGTHS[0]) / (WAVELENGTHS[-1] - WAVELENGTHS[0])
_POWERS: NDArray[np.float64] = np.stack([_T * _T, _T, np.ones_like(_T)], axis=1)
_CACHE: dict[str, NDArray[np.float64]] = {}


def _once(name: str, make) -> NDArray[np.float64]:
    """``make()``, computed once per process (read-only)."""
    if name not in _CACHE:
        value = make()
        value.setflags(write=False)
        _CACHE[name] = value
    return _CACHE[name]


def _light_basis() -> NDArray[np.float64]:
    from grassd.calib.spectral_virtual_camera import mallett_basis

    b = illuminant("D65")[:, None] * mallett_basis()
    rgb = M_XYZ_TO_REC709 @ integrate(b.T, cie_observer()).T  # (3, 3): column k of b_k
    return b @ np.linalg.inv(rgb)


def light_basis() -> NDArray[np.float64]:
    """(n, 3) spectra of unit Rec.709 light per channel on :data:`WAVELENGTHS`: CIE D65 times
    Mallett and Yuksel's basis (white light is D65), mapped so that the CIE observer reads each
    as its unit primary (white light of luminance 1). Read-only, computed once."""
    return _once("light", _light_basis)


def rec709_weights() -> NDArray[np.float64]:
    """(3, n) weights on :data:`WAVELENGTHS` whose product with a reflectance is its linear
    Rec.709 under white light (:func:`light_basis`'s, D65 to 1e-4), as the CIE observer reads
    it: the perfect white reads (1, 1, 1) exactly (trapezoids included). Read-only."""
    return _once("rec709", lambda: M_XYZ_TO_REC709 @ integrate(
        np.diag(light_basis() @ np.ones(3)), cie_observer()).T)


def _sigmoid(x: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Jakob and Hanika's sigmoid ``1/2 + x / (2 sqrt(1 + x^2))`` and its derivative."""
    r = 1.0 / np.sqrt(1.0 + x * x)
    return 0.5 + 0.5 * x * r, 0.5 * r ** 3


def sigmoid_coefficients(albedo_linear: ArrayLike) -> NDArray[np.float64]:
    """(..., 3) Jakob-Hanika coefficients ``(c0, c1, c2)`` of the smooth reflectance whose
    linear Rec.709 under D65 is ``albedo_linear`` (..., 3), each channel held within
    :data:`EDGE` of 0..1 (module docstring). Damped Newton from the grey of the same
    luminance; raises :class:`SpectralPredictionError` for a colour no such spectrum has (far
    outside what a surface reflects).

    >>> c = sigmoid_coefficients([0.18, 0.18, 0.18])
    >>> bool(abs(c[0]) < 1e-9 and abs(c[1]) < 1e-9)
    True
    """
    target = np.clip(np.asarray(albedo_linear, np.float64), EDGE, 1.0 - EDGE)
    shape = target.shape
    target = target.reshape(-1, 3)
    powers = _POWERS  # (n, 3)
    w = rec709_weights()
    y = np.clip(luminance(target, "rec709"), EDGE, 1.0 - EDGE)
    s = 2.0 * y - 1.0
    c = np.zeros_like(target)
    c[:, 2] = s / np.sqrt(1.0 - s * s)

    def residual(coef: NDArray[np.float64], goal: NDArray[np.float64]
                 ) -> tuple[NDArray, NDArray]:
        rho, slope = _sigmoid(coef @ powers.T)  # (m, n)
        return rho @ w.T - goal, slope

    r, slope = residual(c, target)
    for _ in range(MAX_NEWTON_STEPS):
        err = np.abs(r).max(axis=1)
        todo = err > MATCH_TOLERANCE
        if not todo.any():
            break
        jac = np.einsum("cn,mn,nk->mck", w, slope[todo], powers)  # (m, 3, 3)
        step = np.linalg.solve(jac, -r[todo][..., None])[..., 0]
        # Halve the step until the residual falls (the sigmoid flattens far from 0).
        k = np.ones(len(step))
        best = c[todo].copy()
        best_r, best_slope = r[todo].copy(), slope[todo].copy()
        for _ in range(30):
            trial = c[todo] + k[:, None] * step
            tr, ts = residual(trial, target[todo])
            better = np.abs(tr).max(axis=1) < err[todo]
            best[better], best_r[better], best_slope[better] = (
                trial[better], tr[better], ts[better])
            if better.all():
                break
            k = np.where(better, 0.0, 0.5 * k)
        c[todo], r[todo], slope[todo] = best, best_r, best_slope
    bad = np.abs(r).max(axis=1) > 1e-6
    if bad.any():
        raise SpectralPredictionError(
            f"no smooth reflectance has the linear Rec.709 {target[bad][0].round(4).tolist()}"
            " under D65; an albedo must be a colour a surface can reflect")
    return c.reshape(shape)


def sigmoid_spectra(albedo_linear: ArrayLike) -> NDArray[np.float64]:
    """(..., n) smooth reflectance spectra on :data:`WAVELENGTHS` of albedos (..., 3) linear
    Rec.709 (:func:`sigmoid_coefficients`; D65, the white (1, 1, 1))."""
    return _sigmoid(sigmoid_coefficients(albedo_linear) @ _POWERS.T)[0]


def emitter_spectra(rgb: ArrayLike) -> NDArray[np.float64]:
    """(..., n) spectra of lights of linear Rec.709 radiance ``rgb`` (..., 3), each upsampled
    as Mitsuba's spectral variants upsample an emitter's colour: ``2 m * rho(rgb / 2 m) *
    D65``, ``m`` the colour's largest channel and ``rho`` its smooth reflectance
    (:func:`sigmoid_spectra`), on the scale of :func:`light_basis` (white light of luminance
    1 per unit)."""
    c = np.clip(np.asarray(rgb, np.float64), 0.0, None)
    scale = 2.0 * c.max(axis=-1, keepdims=True)
    safe = np.where(scale > 0, scale, 1.0)
    return scale * sigmoid_spectra(c / safe) * (light_basis() @ np.ones(3))


def fitted_light_basis(rgb: ArrayLike, weights: ArrayLike) -> NDArray[np.float64]:
    """(n, 3) basis of the light whose texels have linear Rec.709 radiance ``rgb`` (t, 3) and
    weigh ``weights`` (t,) in a flat white card's irradiance (cosine times solid angle, sr).

    The albedo polynomial's coefficients are linear in the light's channels, so a light is
    upsampled through a linear basis ``B``. This one is the closest, in least squares weighted
    by ``weights``, to each texel's own spectrum (:func:`emitter_spectra`), among the bases that
    (a) give the white card exactly the spectrum its texels give it, ``B sum w c = sum w s``,
    and (b) the CIE observer reads as the unit primaries (solved as one equality-constrained
    least squares, its KKT system)."""
    c = np.asarray(rgb, np.float64).reshape(-1, 3)
    w = np.asarray(weights, np.float64).reshape(-1)
    keep = (w > 0) & (c.max(axis=1) > 0)
    c, w = c[keep], w[keep]
    if len(c) < 3:
        return light_basis()
    # The basis is the same for the light at any scale: solve at unit mean radiance and unit
    # total weight, where the KKT system below is well conditioned.
    w = w / w.sum()
    c = c / float(w @ c.mean(axis=1))
    spectra = emitter_spectra(c)  # (t, n)
    n = len(WAVELENGTHS)
    gram = (c * w[:, None]).T @ c  # (3, 3): the Hessian of every wavelength's row
    target = (spectra * w[:, None]).T @ c  # (n, 3)
    white_rgb, white_spectrum = w @ c, w @ spectra
    a = M_XYZ_TO_REC709 @ integrate(np.eye(n), cie_observer()).T  # (3, n) observer readout
    # Unknowns: B row-major (wavelength, channel). Constraints: each row dotted with the
    # white's colour gives the white's spectrum there; the readout of each column is e_k.
    hess = np.kron(np.eye(n), gram)
    white_rows = np.kron(np.eye(n), white_rgb[None, :])  # (n, 3n)
    primary_rows = np.stack([np.kron(a[j], np.eye(3)[k]) for j in range(3) for k in range(3)])
    cons = np.vstack([white_rows, primary_rows])
    kkt = np.block([[hess, cons.T], [cons, np.zeros((len(cons), len(cons)))]])
    rhs = np.concatenate([target.reshape(-1), white_spectrum, np.eye(3).reshape(-1)])
    x = np.linalg.lstsq(kkt, rhs, rcond=None)[0]
    return x[:3 * n].reshape(n, 3)


def transfer(monomial_spectra: ArrayLike, response: ArrayLike,
             basis: ArrayLike | None = None) -> NDArray[np.float64]:
    """(..., M, 3, C) ``T_mkc = integral monomial_m(lambda) basis_k(lambda) response_c(lambda)``:
    what a unit coefficient of monomial ``m`` in light channel ``k`` gives channel ``c`` of a
    sensor of ``response`` (n, C) (a camera's sensitivities or the CIE observer), from the
    monomials' spectra (..., M, n) on :data:`WAVELENGTHS` (:func:`grassd.sim.albedo_terms.
    monomial_values` of the materials' :func:`sigmoid_spectra`) and the light's ``basis``
    (n, 3) (default :func:`light_basis` of D65)."""
    b = light_basis() if basis is None else np.asarray(basis, np.float64)
    spectra = np.asarray(monomial_spectra, np.float64)[..., None, :] * b.T
    return integrate(spectra, response)


@dataclass(frozen=True)
class Development:
    """How a photo turns a camera's raw RGB into ProPhoto, and its exposure.

    ``sensitivities`` (n, 3) the camera's, on :data:`WAVELENGTHS`; ``multipliers`` (3,) the
    photo's white balance (R, G, B, from the checker's grey); ``rgb_cam`` (3, 3) LibRaw's camera
    -> linear sRGB of the photo's profile (:func:`grassd.calib.checker_photo.raw_rgb_cam`);
    ``grey_y``: the checker grey's reference luminance (0..1).
    """

    sensitivities: NDArray[np.float64]
    multipliers: NDArray[np.float64]
    rgb_cam: NDArray[np.float64]
    grey_y: float

    @classmethod
    def of_profile(cls, sensitivities: ArrayLike, multipliers: ArrayLike,
                   xyz_to_camera: ArrayLike, grey_y: float) -> Development:
        """A development whose ``rgb_cam`` LibRaw builds from a DNG's ColorMatrix
        (:func:`grassd.calib.camera_response.rgb_cam`)."""
        return cls(np.asarray(sensitivities, np.float64),
                   np.asarray(multipliers, np.float64)[:3], rgb_cam(xyz_to_camera), grey_y)

    def develop(self, raw: ArrayLike) -> NDArray[np.float64]:
        """(..., 3) ProPhoto linear of raw RGB (..., 3), unscaled (no clipping)."""
        srgb = (np.asarray(raw, np.float64) * self.multipliers[:3]) @ self.rgb_cam.T
        return srgb @ M_REC709_TO_PROPHOTO.T

    def exposure(self, white_raw: ArrayLike) -> float:
        """The factor that puts the checker's grey at ``Y = 0.18``: the grey is a flat
        spectrum of luminance ``grey_y`` under the light whose white card reads ``white_raw``
        (3,) raw RGB."""
        y = float(luminance(self.develop(np.asarray(white_raw, np.float64) * self.grey_y)))
        if not y > 0:
            raise SpectralPredictionError("the white card develops to black: check the "
                                          "camera's sensitivities and the photo's profile")
        return GREY_CARD_Y / y
