"""Spectral light transport for the simulated characteristic: what RGB transport leaves out.

The renderer carries light in linear Rec.709, three channels: a path's colour is the product of
the materials' Rec.709 albedos times the light's Rec.709 radiance. Light and reflectance are
spectra, and a product of spectra read by the CIE observer is not the product of their Rec.709
readings, more so the more surfaces a path meets, so RGB transport moves a pale or saturated
pixel's characteristic (docs/calibration.md, "Spectral transport", measures by how much).

Spectral transport is added to the trace as a difference measured on recorded paths
(:class:`SpectralTransport`): the renderer's recording mode
(:meth:`grassd.sim.renderer.Renderer.albedo_terms`, deep, with the tail term) gives each
replicate's radiance as a polynomial in the materials, which is evaluated twice on the same
paths, on the albedos' Rec.709 (what the trace computes) and per wavelength on the materials'
Jakob-Hanika spectra (:func:`grassd.calib.spectral_prediction.sigmoid_spectra`) in the light's
upsampled spectra (:func:`light_spectra_basis`), read by the CIE observer as linear Rec.709.
The difference of the two, added to the trace's replicate, makes the replicate an unbiased
estimate of the spectral radiance (the trace and the difference each estimate their own
expectation; a path's vertices beyond the polynomial's degree keep their Rec.709 reflectance,
the tail term), and its noise enters the replicates' spread, so the standard errors hold it. The
two evaluations share their paths, so the difference varies little from path to path and a
fraction of the trace's paths measures it (:attr:`SpectralTransport.share`; a recorded path
costs several traced ones).

The light's basis is fitted so that the observer reads a flat white card exactly as the
Rec.709 transport does: the white reference, and so the normalisation, is the same in both.

Units: radiance in the scaled light's units (nits), linear Rec.709.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import NDArray

from grassd.calib.camera_response import cie_observer
from grassd.calib.colour_spaces import M_XYZ_TO_REC709
from grassd.calib.spectral_prediction import fitted_light_basis, sigmoid_spectra, transfer
from grassd.sim.albedo_terms import TERM_DEGREE, monomial_values
from grassd.sim.lighting import Lighting, horizontal_cosine_weights
from grassd.sim.scene import DisplaySpec, RenderSettings, Viewpoint

#: The light's map is block-averaged to at most this many rows (and twice as many columns)
#: before its texels are upsampled to spectra (:func:`light_spectra_basis`).
BASIS_ROWS: int = 128


def light_spectra_basis(lighting: Lighting) -> NDArray[np.float64]:
    """(n, 3) basis of ``lighting``'s spectra (:func:`grassd.calib.spectral_prediction.
    fitted_light_basis`): the map's texels above the horizon, block-averaged to at most
    :data:`BASIS_ROWS` rows, and the sun, each weighted by what it gives a flat white card
    (radiance times cosine times solid angle)."""
    env = np.asarray(lighting.env, np.float64)
    k = max(1, int(np.ceil(env.shape[0] / BASIS_ROWS)))
    h, w = env.shape[0] // k * k, env.shape[1] // k * k
    env = env[:h, :w].reshape(h // k, k, w // k, k, 3).mean(axis=(1, 3))
    weights = horizontal_cosine_weights(*env.shape[:2])  # (rows,)
    rgb = env.reshape(-1, 3)
    share = (env.mean(axis=2) * weights[:, None]).reshape(-1)
    if lighting.sun_direction is not None and lighting.sun_direction[2] > 0:
        sun = np.asarray(lighting.sun_irradiance_rgb, np.float64)
        rgb = np.vstack([rgb, sun])
        share = np.append(share, sun.mean() * float(lighting.sun_direction[2]))
    return fitted_light_basis(rgb, share)


@functools.cache
def _observer_rec709() -> NDArray[np.float64]:
    """(n, 3) the CIE observer read as linear Rec.709."""
    return cie_observer() @ M_XYZ_TO_REC709.T


@dataclass(frozen=True)
class SpectralTransport:
    """The difference spectral transport makes to a display's trace under one light.

    ``albedo`` (4, 3): the pixel's linear Rec.709 albedos (material order); ``spectra`` (4, n):
    their smooth reflectances; ``basis`` (n, 3): the light's spectra per Rec.709 channel
    (:func:`light_spectra_basis`); ``specular``: the pixel's glossy reflectance; ``share``: the
    recording traces ``1/share`` of the trace's paths.
    """

    albedo: NDArray[np.float64]
    spectra: NDArray[np.float64]
    basis: NDArray[np.float64]
    specular: float
    share: int
    _matrices: dict[int, tuple[NDArray[np.float64], NDArray[np.float64]]] = field(
        default_factory=dict, repr=False, compare=False)

    @classmethod
    def of(cls, display: DisplaySpec, lighting: Lighting, share: int) -> SpectralTransport:
        """The transport of ``display``'s pixel under ``lighting`` (the light's basis is a
        least-squares solve over its texels: once per light)."""
        albedo = display.pixel.albedo_linear
        return cls(albedo, sigmoid_spectra(albedo), light_spectra_basis(lighting),
                   float(display.pixel.specular), share)

    def matrices(self, degree: int) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """The monomials of ``degree`` at the albedos' Rec.709 (M, 3), and (M, 3, 3) what a
        unit coefficient of each monomial in each light channel gives the observer's linear
        Rec.709 on the materials' spectra in the light's
        (:func:`grassd.calib.spectral_prediction.transfer`)."""
        if degree not in self._matrices:
            self._matrices[degree] = (monomial_values(self.albedo, self.specular, degree),
                                      self.observed(self.spectra, degree))
        return self._matrices[degree]

    def observed(self, spectra: NDArray[np.float64], degree: int) -> NDArray[np.float64]:
        """(..., M, 3, 3) what a unit coefficient of each monomial of ``degree`` in each light
        channel gives the observer's linear Rec.709 on reflectance ``spectra`` (..., 4, n)
        (material order, :data:`~grassd.calib.spectral_prediction.WAVELENGTHS`) in this
        light (:func:`grassd.calib.spectral_prediction.transfer`): the pixel's materials, or
        the same materials faded or enriched."""
        return transfer(monomial_values(spectra, self.specular, degree), _observer_rec709(),
                        self.basis)

    def difference(self, renderer, display: DisplaySpec, lighting: Lighting,
                   viewpoint: Viewpoint, lengths_mm: NDArray[np.float64],
                   settings: RenderSettings, pixel_index: int = 0
                   ) -> tuple[NDArray[np.float64], float]:
        """(R, n, 3) spectral minus Rec.709 radiance (nits) of ``settings.replicates``
        replicates at ``lengths_mm`` (mm), recorded on ``settings.samples / share`` paths
        each with the replicates' seed, and the recording's seconds."""
        recording = replace(settings, samples=max(1, settings.samples // self.share))
        terms = renderer.albedo_terms(display, lighting, viewpoint, lengths_mm, recording,
                                      pixel_index=pixel_index, glossy=self.specular > 0,
                                      degree=TERM_DEGREE)
        rgb, spectral = self.matrices(terms.degree)
        c = terms.coefficients  # (R, n, M, 3)
        return (np.einsum("rnmk,mkc->rnc", c, spectral) - np.einsum("rnmc,mc->rnc", c, rgb),
                terms.seconds.get("trace", 0.0))
