"""How ``grassd validate`` and ``grassd fit`` turn the simulation into what a photo shows.

Both compare a capture's photos (developed ProPhoto, the checker's grey at ``Y = 0.18``, CIELAB)
with the simulated pixel, whose radiance the albedo polynomial gives per Rec.709 channel of the
light (:class:`grassd.sim.albedo_terms.AlbedoTerms`). A chain evaluates the polynomial for the
materials and carries it the rest of the way:

* :class:`CorrectedChain` (the capture names no sensitivities): the polynomial on the albedos'
  Rec.709 (RGB transport), normalised by the white card, through the colour correction fitted
  from the virtual to the photographed checker (:func:`grassd.calib.ccm.select_ccm`);
* :class:`CameraChain` (``camera_sensitivities`` in ``capture.toml``): the polynomial on the
  materials' smooth spectra under the light's spectrum, integrated against the camera's own
  sensitivities into its raw RGB, developed with the photo's white balance and profile and
  exposed as the photo is (:mod:`grassd.calib.spectral_prediction`): spectral transport and the
  camera's own response, no correction.

A chain's *signal* is what its :meth:`lab` reads: normalised linear Rec.709 for the corrected
chain, developed ProPhoto for the camera's.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from grassd.calib.camera_response import (
    COLOUR_CAMERAS,
    CameraSensitivities,
    read_sensitivities,
)
from grassd.calib.ccm import ColourCorrection
from grassd.calib.charts import ReferenceChart
from grassd.calib.checker_photo import raw_rgb_cam
from grassd.calib.colour_spaces import luminance, prophoto_to_lab, rec709_to_prophoto
from grassd.calib.ogcd import OGCDResult, ogcd_from_samples
from grassd.calib.spectral_prediction import (
    Development,
    sigmoid_spectra,
    transfer,
)
from grassd.daemon.core.calibration.simulation import white_radiance
from grassd.daemon.core.calibration.transport import light_spectra_basis
from grassd.sim.albedo_terms import monomial_values
from grassd.sim.lighting import Lighting

#: Transfer matrices a camera chain keeps (the fit evaluates a few materials at a time).
TRANSFER_CACHE: int = 16


def chain_text(form: str) -> str:
    """How a report says which chain read the simulation (a chain's :attr:`~ColourChain.form`)."""
    if form == CameraChain.form:
        return "the camera's spectral sensitivities, no correction"
    return f"the checker's correction ({form})"


class ColourChain(Protocol):
    """What the fit and validate need of a chain (module docstring)."""

    #: the chain's name in reports: a correction's form, or ``"camera"``
    form: str

    def signal(self, coefficients: NDArray[np.float64], albedo: NDArray[np.float64],
               ks: float, degree: int) -> NDArray[np.float64]:
        """(..., 3) signal of polynomial coefficients (..., M, 3) at albedos (4, 3) linear
        Rec.709 and glossy ``ks``, monomials of ``degree``."""
        ...

    def lab(self, signal: NDArray[np.float64]) -> NDArray[np.float64]:
        """(..., 3) D50 CIELAB of signals (..., 3)."""
        ...

    def ogcd(self, samples: NDArray[np.float64]) -> OGCDResult:
        """OGCD of the mean of independent signal samples (S, n, 3), with its errors."""
        ...


@dataclass(frozen=True)
class CorrectedChain:
    """RGB transport read through a colour correction (module docstring).

    ``ccm``: the correction from the simulation's ProPhoto, already scaled
    (:meth:`~grassd.calib.ccm.ColourCorrection.scaled`); ``white`` (3,): the white card's
    Rec.709 radiance (nits), by which the simulation is normalised.
    """

    ccm: ColourCorrection
    white: NDArray[np.float64]

    @property
    def form(self) -> str:
        """The correction's form (:data:`grassd.calib.ccm.CCM_FORMS`)."""
        return self.ccm.form

    def signal(self, coefficients: NDArray[np.float64], albedo: NDArray[np.float64],
               ks: float, degree: int) -> NDArray[np.float64]:
        """Normalised linear Rec.709 (the white card reads 1)."""
        mono = monomial_values(albedo, ks, degree)
        return np.einsum("...mc,mc->...c", coefficients, mono) / self.white

    def lab(self, signal: NDArray[np.float64]) -> NDArray[np.float64]:
        """CIELAB of normalised Rec.709 through the correction."""
        return prophoto_to_lab(self.ccm.apply(rec709_to_prophoto(np.clip(signal, 0.0, None))))

    def ogcd(self, samples: NDArray[np.float64]) -> OGCDResult:
        """OGCD through the correction (:func:`grassd.calib.ogcd.ogcd_from_samples`)."""
        return ogcd_from_samples(np.clip(samples, 0.0, None), space="rec709", ccm=self.ccm)


@dataclass
class CameraChain:
    """Spectral transport read by the camera's own sensitivities (module docstring).

    ``development``: the photos' (their white balance, profile and the camera's
    sensitivities); ``white`` (3,): the white card's Rec.709 radiance (nits), which sets the
    exposure as the checker's grey sets the photos'; ``basis`` (n, 3): the light's spectra per
    Rec.709 channel (:func:`~grassd.daemon.core.calibration.transport.light_spectra_basis`).
    """

    development: Development
    white: NDArray[np.float64]
    basis: NDArray[np.float64]
    form: str = "camera"
    _transfers: dict[tuple, NDArray[np.float64]] = field(default_factory=dict, repr=False)

    def __post_init__(self) -> None:
        flat = transfer(np.ones((1, len(self.development.sensitivities))),
                        self.development.sensitivities, self.basis)[0]  # (3, 3)
        self.exposure = self.development.exposure(np.asarray(self.white) @ flat)

    def transfer(self, albedo: NDArray[np.float64], ks: float, degree: int
                 ) -> NDArray[np.float64]:
        """(M, 3, 3) from coefficients to the camera's raw RGB at these materials
        (:func:`grassd.calib.spectral_prediction.transfer`), kept for the last few."""
        a = np.asarray(albedo, np.float64)
        key = (a.tobytes(), float(ks), degree)
        if key not in self._transfers:
            if len(self._transfers) >= TRANSFER_CACHE:
                self._transfers.pop(next(iter(self._transfers)))
            spectra = monomial_values(sigmoid_spectra(a), ks, degree)  # (M, n)
            self._transfers[key] = transfer(spectra, self.development.sensitivities,
                                             self.basis)
        return self._transfers[key]

    def signal(self, coefficients: NDArray[np.float64], albedo: NDArray[np.float64],
               ks: float, degree: int) -> NDArray[np.float64]:
        """Developed ProPhoto linear at the photos' exposure."""
        raw = np.einsum("...mk,mkc->...c", coefficients, self.transfer(albedo, ks, degree))
        return self.development.develop(raw) * self.exposure

    def lab(self, signal: NDArray[np.float64]) -> NDArray[np.float64]:
        """CIELAB of developed ProPhoto, as the photos are read."""
        return prophoto_to_lab(np.clip(signal, 0.0, None))

    def ogcd(self, samples: NDArray[np.float64]) -> OGCDResult:
        """OGCD of developed ProPhoto (:func:`grassd.calib.ogcd.ogcd_from_samples`)."""
        return ogcd_from_samples(np.clip(samples, 0.0, None), space="prophoto")


def load_sensitivities(name: str) -> CameraSensitivities:
    """A camera's sensitivities named in a capture: the path of a CSV
    (:func:`grassd.calib.camera_response.read_sensitivities`) or a camera of
    colour-science's datasets (:data:`grassd.calib.camera_response.COLOUR_CAMERAS`)."""
    if name in COLOUR_CAMERAS:
        return CameraSensitivities.from_colour(name)
    return read_sensitivities(name)


def simulation_chain(sensitivities: str | None, correction: ColourCorrection, scale: float,
                     lighting: Lighting, white_balance: Sequence[float],
                     checker_photo: Path, chart: ReferenceChart) -> ColourChain:
    """The chain of a capture: the camera's (:class:`CameraChain`) where it names the camera's
    ``sensitivities`` (:func:`load_sensitivities`), developed as its ``checker_photo`` is (its
    profile, the capture's ``white_balance``, the ``chart``'s grey) under ``lighting``'s
    spectra, else the checker's ``correction`` scaled by ``scale`` (:class:`CorrectedChain`)."""
    white = white_radiance(lighting)
    if sensitivities is None:
        return CorrectedChain(correction.scaled(scale), white)
    camera = load_sensitivities(sensitivities)
    grey_y = float(luminance(chart.prophoto()[chart.grey_index()], "prophoto"))
    development = Development(camera.values, np.asarray(white_balance, np.float64)[:3],
                              raw_rgb_cam(checker_photo), grey_y)
    return CameraChain(development, white, light_spectra_basis(lighting))
