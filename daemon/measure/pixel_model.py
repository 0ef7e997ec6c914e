"""Every pixel's colour as a function of its grass length and its departures from the model.

The renderer records each pixel's radiance at its own viewpoint on a grid of green lengths as a
polynomial in the materials (:meth:`grassd.sim.renderer.Renderer.albedo_terms`, after
Ben-Artzi et al. 2008). A :class:`~grassd.daemon.core.calibration.variation.DisplayVariation` then
costs one contraction: its gains scale the yellow and green albedos (linear), its offset shifts the
length at which the grid is read (linear interpolation, clamped to the mechanism's range).

Three uses, one type (:class:`PixelColourModel`):

* the hidden truth of a simulated display (each pixel its own tuft layout);
* the model ``grassd measure`` fits to the photos of the display (:func:`fit_variation`);
* the models of the configured viewers, through which the fitted variation is carried to the
  viewpoints the display serves (:func:`corrected_commands`).

Units: lengths mm, colours white-normalised linear Rec.709 (a white card lying at the display
reads 1), CIELAB D50 through ProPhoto (:func:`grassd.calib.colour_spaces.prophoto_to_lab`),
colour differences CIEDE2000.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from functools import cached_property
from typing import TYPE_CHECKING

import numpy as np
from colour import delta_E
from numpy.typing import NDArray

from grassd.calib.colour_spaces import prophoto_to_lab, rec709_to_prophoto
from grassd.daemon.core.calibration.variation import GAIN_RANGE, OFFSET_LIMIT_MM, DisplayVariation

if TYPE_CHECKING:
    from grassd.daemon.core.calibration.transport import SpectralTransport
    from grassd.daemon.measure.neighbours import NeighbourShares
    from grassd.sim.lighting import Lighting
    from grassd.sim.renderer import Renderer
    from grassd.sim.scene import DisplaySpec, RenderSettings, Viewpoint

#: Material rows of the albedo matrix (the renderer's symbol order).
YELLOW, GREEN = 0, 1


@dataclass(frozen=True, eq=False)
class PixelColourModel:
    """N pixels' recorded radiance terms on one grid of green lengths.

    ``grid_mm`` (G,) lengths; ``coefficients`` (N, G, 56, 3) terms (mean over replicates and
    layouts, nits per unit monomial); ``white`` (3,) the white card's radiance (nits);
    ``albedo`` (4, 3) the model pixel's linear albedos; ``specular`` its glossy ``ks``;
    ``layout_sd`` (N, G, 3) the standard deviation of the model pixel's CIELAB over the tuft
    layouts averaged (None with one layout): how much a real pixel, one layout, may differ.
    ``transport``: the light's and the materials' spectra with spectral transport (the terms
    are read per wavelength and by the CIE observer, the gains scaling the materials'
    reflectance spectra), None with Rec.709 transport (the terms read on the Rec.709 albedos).
    ``neighbours``: which pixels' grass the eye sees through each pixel's quad
    (:class:`~grassd.daemon.measure.neighbours.NeighbourShares`): a pixel's gains are then
    seen mixed with its neighbours', as the variation gives them; None: each pixel alone.
    """

    grid_mm: NDArray[np.float64]
    coefficients: NDArray[np.float64]
    white: NDArray[np.float64]
    albedo: NDArray[np.float64]
    specular: float = 0.0
    layout_sd: NDArray[np.float64] | None = None
    transport: SpectralTransport | None = None
    neighbours: NeighbourShares | None = None

    @property
    def n_pixels(self) -> int:
        """Number of pixels N."""
        return self.coefficients.shape[0]

    def scaled(self, factor: float) -> PixelColourModel:
        """The same pixels under the same light ``factor`` times as bright (the white card's
        normalisation is unchanged; :meth:`radiance` scales)."""
        return replace(self, coefficients=self.coefficients * factor, white=self.white * factor)

    def grid_radiance(self, variation: DisplayVariation, pixels: NDArray | None = None
                      ) -> NDArray[np.float64]:
        """(n, G, 3) radiance (nits) of the chosen ``pixels`` (default all) on the grid."""
        from grassd.sim.albedo_terms import MAX_DEGREE, monomial_values

        idx = np.arange(self.n_pixels) if pixels is None else np.asarray(pixels)
        gains = self._seen_gains(variation, idx)
        reflectance = self.albedo if self.transport is None else self.transport.spectra
        if all(g.min() >= 0.0 and g.max() * reflectance[m].max() <= 1.0
               for m, g in zip((YELLOW, GREEN), gains, strict=True)):  # nothing clips
            y, g = (gain[..., None] ** _GAIN_POWERS[:, m] for m, gain in enumerate(gains))
            return np.einsum("ngpc,ngp->ngc", self._by_gain_power[idx], np.broadcast_to(
                y * g, (len(idx), len(self.grid_mm), len(_GAIN_POWERS))))
        coefficients = self.coefficients[idx]
        if self.transport is None:
            mono = monomial_values(_varied(self.albedo, *gains), self.specular)
            return np.einsum("ngmc,ngmc->ngc", coefficients,
                             np.broadcast_to(mono, coefficients.shape))
        observed = self.transport.observed(_varied(self.transport.spectra, *gains),
                                           MAX_DEGREE)  # (n, G or 1, 56, 3, 3)
        return np.einsum("ngmk,ngmkc->ngc", coefficients,
                         np.broadcast_to(observed, coefficients.shape[:3] + (3, 3)))

    @cached_property
    def _by_gain_power(self) -> NDArray[np.float64]:
        """(N, G, P, 3) the radiance's terms gathered by their powers of the yellow and the
        green gain (:data:`_GAIN_POWERS`): each monomial's value at the model's materials,
        read with the model's transport. Scaling a material by a gain scales a monomial by
        the gain to its power, so a variation costs P terms (until a reflectance clips at
        1)."""
        from grassd.sim.albedo_terms import MAX_DEGREE, monomial_values, monomials_of

        rows = monomials_of(MAX_DEGREE)
        group = (rows[:, None, YELLOW] == _GAIN_POWERS[None, :, 0]) & (
            rows[:, None, GREEN] == _GAIN_POWERS[None, :, 1])  # (56, P)
        if self.transport is None:
            unit = monomial_values(self.albedo, self.specular)  # (56, 3)
            return np.einsum("ngmc,mc,mp->ngpc", self.coefficients, unit, group)
        observed = self.transport.observed(self.transport.spectra, MAX_DEGREE)  # (56, 3, 3)
        return np.einsum("ngmk,mkc,mp->ngpc", self.coefficients, observed, group)

    def _seen_gains(self, variation: DisplayVariation, idx: NDArray
                    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """The yellow and green gains of pixels ``idx`` as the eye sees them: (n, G) mixed
        with the neighbours' (:attr:`neighbours`), or (n, 1) each pixel's own."""
        if self.neighbours is None:
            return variation.yellow_gain[idx, None], variation.green_gain[idx, None]
        return (self.neighbours.seen(variation.yellow_gain, YELLOW, idx),
                self.neighbours.seen(variation.green_gain, GREEN, idx))

    def radiance(self, commanded_mm: NDArray, variation: DisplayVariation,
                 pixels: NDArray | None = None) -> NDArray[np.float64]:
        """(n, K, 3) radiance (nits) of the chosen ``pixels`` commanded to ``commanded_mm``
        ((K,) for every pixel, or (n, K)): the grid read at commanded + offset, clamped to it."""
        idx = np.arange(self.n_pixels) if pixels is None else np.asarray(pixels)
        grid = self.grid_radiance(variation, idx)
        cmd = np.broadcast_to(np.asarray(commanded_mm, dtype=np.float64),
                              (len(idx), np.shape(commanded_mm)[-1]))
        length = np.clip(cmd + variation.length_offset_mm[idx, None], self.grid_mm[0],
                         self.grid_mm[-1])
        j = np.clip(np.searchsorted(self.grid_mm, length) - 1, 0, len(self.grid_mm) - 2)
        g0, g1 = self.grid_mm[j], self.grid_mm[j + 1]
        w = ((length - g0) / (g1 - g0))[..., None]
        rows = np.arange(len(idx))[:, None]
        return grid[rows, j] * (1.0 - w) + grid[rows, j + 1] * w

    def rgb(self, commanded_mm: NDArray, variation: DisplayVariation,
            pixels: NDArray | None = None) -> NDArray[np.float64]:
        """(n, K, 3) white-normalised linear Rec.709 (see :meth:`radiance`)."""
        return self.radiance(commanded_mm, variation, pixels) / self.white


#: (P, 2) the powers of the yellow and the green gain a degree-3 monomial may hold.
_GAIN_POWERS: NDArray[np.int64] = np.array([(a, b) for a in range(4) for b in range(4 - a)])


def _varied(reflectance: NDArray, yellow_gain: NDArray, green_gain: NDArray
            ) -> NDArray[np.float64]:
    """(n, g, 4, C) the materials' reflectance (4, C) (Rec.709 albedos or spectra), the
    yellow and green scaled by the gains (n, g) within 0..1."""
    r = np.broadcast_to(reflectance, np.shape(green_gain) + np.shape(reflectance)).copy()
    r[..., YELLOW, :] = np.clip(r[..., YELLOW, :] * yellow_gain[..., None], 0.0, 1.0)
    r[..., GREEN, :] = np.clip(r[..., GREEN, :] * green_gain[..., None], 0.0, 1.0)
    return r


def lab_of(rgb: NDArray, ccm: NDArray | None = None) -> NDArray[np.float64]:
    """CIELAB of white-normalised linear Rec.709 ``rgb`` (..., 3), through a camera's colour
    correction ``ccm`` (3 x 3 on ProPhoto, scale included) when given."""
    pp = rec709_to_prophoto(np.clip(rgb, 0.0, None))
    return prophoto_to_lab(pp if ccm is None else pp @ np.asarray(ccm).T)


def record_pixel_model(renderer: Renderer, display: DisplaySpec, lighting: Lighting,
                       viewpoints: Sequence[Viewpoint], grid_mm: NDArray,
                       settings: RenderSettings, *, layouts: int = 1, glossy: bool = False,
                       transport: SpectralTransport | None = None, neighbours: bool = True,
                       progress: Callable[[int, int], None] | None = None) -> PixelColourModel:
    """Record every pixel of ``display`` (a ``DisplaySpec``) at its own viewpoint
    (``viewpoints[i]``, a ``Viewpoint``) on ``grid_mm`` under ``lighting``, averaged over
    ``layouts`` tuft layouts (layout seeds ``pixel.layout_seed + k``). ``settings``:
    ``RenderSettings``; the polynomial has degree 3 (56 monomials), and a path's vertices
    beyond it (``max_bounces`` above 3, Russian roulette ending the paths) are its tail term
    (:mod:`grassd.sim.albedo_terms`): exact at the model's own albedos, the tail's vertices
    keeping them as the gains move the others. ``transport``: the model's
    (:attr:`PixelColourModel.transport`). ``neighbours``: record which pixels' grass each
    quad shows (:attr:`PixelColourModel.neighbours`, the layouts' mean). ``progress(done,
    total)`` counts recordings."""
    from grassd.daemon.core.calibration.simulation import layout_display, white_radiance
    from grassd.daemon.measure.neighbours import NeighbourShares, record_neighbour_shares
    from grassd.sim.albedo_terms import MAX_DEGREE, n_monomials

    grid = np.asarray(grid_mm, dtype=np.float64)
    n = display.rows * display.cols
    if len(viewpoints) != n:
        raise ValueError(f"{len(viewpoints)} viewpoints for {n} pixels")
    total, done = n * layouts, 0
    recorded = []  # per layout (N, G, 56, 3)
    shares = []
    for k in range(layouts):
        disp = layout_display(display, k)
        if neighbours:
            shares.append(record_neighbour_shares(renderer, disp, lighting, viewpoints, grid))
        one = np.zeros((n, len(grid), n_monomials(MAX_DEGREE), 3))
        for i in range(n):
            terms = renderer.albedo_terms(disp, lighting, viewpoints[i], grid, settings,
                                          pixel_index=i, glossy=glossy, degree=MAX_DEGREE)
            one[i] = terms.coefficients.mean(axis=0)
            done += 1
            if progress:
                progress(done, total)
        recorded.append(one)
    white = np.asarray(white_radiance(lighting), dtype=np.float64)
    model = PixelColourModel(grid_mm=grid, coefficients=np.mean(recorded, axis=0), white=white,
                             albedo=display.pixel.albedo_linear,
                             specular=float(display.pixel.specular), transport=transport,
                             neighbours=NeighbourShares.mean(shares) if shares else None)
    if layouts == 1:
        return model
    none = DisplayVariation.none(n)
    labs = [lab_of(replace(model, coefficients=one).grid_radiance(none) / white)
            for one in recorded]
    return replace(model, layout_sd=np.std(labs, axis=0, ddof=1))


@dataclass(frozen=True, eq=False)
class VariationFit:
    """What :func:`fit_variation` found: the ``variation``, per pixel the RMS CIELAB residual
    ``rms_lab`` (N,) over the photographed lengths and the model's RMS residual with no
    variation ``rms_lab_model`` (N,), and ``colour`` (3, 3): the display-wide colour balance
    (diagonal, linear ProPhoto) between the model's colours and the photographed ones that the
    pixels share (camera chain and any uniform change of the display together; identity when not
    fitted)."""

    variation: DisplayVariation
    rms_lab: NDArray[np.float64]
    rms_lab_model: NDArray[np.float64]
    colour: NDArray[np.float64]


def _fit_pixels(model: PixelColourModel, cmd: NDArray, meas: NDArray, ccm: NDArray | None,
                around: DisplayVariation
                ) -> tuple[DisplayVariation, NDArray[np.float64], NDArray[np.float64]]:
    """Each pixel's offset and gains by least squares on CIELAB (see :func:`fit_variation`),
    its neighbours held at ``around``: (variation, rms residual, rms residual of the model
    pixel)."""
    from scipy.optimize import least_squares

    n = model.n_pixels
    est = DisplayVariation.none(n)
    rms, rms0 = np.zeros(n), np.zeros(n)
    lo = [-OFFSET_LIMIT_MM, GAIN_RANGE[0], GAIN_RANGE[0]]
    hi = [OFFSET_LIMIT_MM, GAIN_RANGE[1], GAIN_RANGE[1]]
    weight = _weights(model, cmd)
    for i in range(n):
        one = np.array([i])

        def residual(x: NDArray, i: int = i, one: NDArray = one) -> NDArray:
            v = DisplayVariation(around.length_offset_mm.copy(), around.green_gain.copy(),
                                 around.yellow_gain.copy())
            v.length_offset_mm[i], v.green_gain[i], v.yellow_gain[i] = x
            return ((lab_of(model.rgb(cmd[i], v, one), ccm)[0] - meas[i])
                    * weight[i]).ravel()

        w = weight[i].ravel()
        rms0[i] = np.sqrt(np.mean((residual(np.array([0.0, 1.0, 1.0])) / w) ** 2))
        best = None
        for x0 in ([0.0, 1.0, 1.0], [0.8, 1.0, 1.0], [-0.8, 1.0, 1.0]):  # offsets are not
            r = least_squares(residual, x0, bounds=(lo, hi), x_scale=[0.5, 0.1, 0.1])  # convex
            if best is None or r.cost < best.cost:
                best = r
        est.length_offset_mm[i], est.green_gain[i], est.yellow_gain[i] = best.x
        rms[i] = np.sqrt(np.mean((best.fun / w) ** 2))  # CIELAB, unweighted
    if model.neighbours is not None:
        est, rms = _fit_jointly(model, cmd, meas, ccm, est, weight)
    return est, rms, rms0


def _fit_jointly(model: PixelColourModel, cmd: NDArray, meas: NDArray, ccm: NDArray | None,
                 start: DisplayVariation, weight: NDArray
                 ) -> tuple[DisplayVariation, NDArray[np.float64]]:
    """Every pixel's offset and gains at once from ``start``, by least squares on all pixels'
    weighted CIELAB residuals: where a quad shows its neighbours' grass
    (:attr:`PixelColourModel.neighbours`), a pixel's gains show in its neighbours' colours
    too, and the fit uses both (the Jacobian's sparsity: a pixel's colours depend on its own
    offset and its neighbourhood's gains). Returns the variation and each pixel's RMS CIELAB
    residual."""
    from scipy.optimize import least_squares
    from scipy.sparse import lil_matrix

    n, k = cmd.shape
    sparsity = lil_matrix((n * k * 3, 3 * n), dtype=np.int8)
    for i, around in enumerate(model.neighbours.index):
        rows = slice(i * k * 3, (i + 1) * k * 3)
        sparsity[rows, i] = 1
        for j in around[around >= 0]:
            sparsity[rows, n + j] = sparsity[rows, 2 * n + j] = 1

    def residual(x: NDArray) -> NDArray:
        v = DisplayVariation(x[:n], x[n:2 * n], x[2 * n:])
        return ((lab_of(model.rgb(cmd, v), ccm) - meas) * weight).ravel()

    lo = np.repeat([-OFFSET_LIMIT_MM, GAIN_RANGE[0], GAIN_RANGE[0]], n)
    hi = np.repeat([OFFSET_LIMIT_MM, GAIN_RANGE[1], GAIN_RANGE[1]], n)
    x0 = np.concatenate([start.length_offset_mm, start.green_gain, start.yellow_gain])
    fit = least_squares(residual, np.clip(x0, lo, hi), bounds=(lo, hi), jac_sparsity=sparsity,
                        x_scale=np.repeat([0.5, 0.1, 0.1], n))
    lab = (fit.fun / weight.ravel()).reshape(n, k * 3)  # CIELAB, unweighted
    return (DisplayVariation(fit.x[:n], fit.x[n:2 * n], fit.x[2 * n:]),
            np.sqrt(np.mean(lab ** 2, axis=1)))


#: CIELAB noise floor of a photographed pixel (camera noise, sampling), for the fit's weights.
PHOTO_LAB_SD: float = 0.3


def _weights(model: PixelColourModel, cmd: NDArray) -> NDArray[np.float64]:
    """(N, K, 3) residual weights: 1 / sqrt(layout sd^2 + photo sd^2) at the commanded lengths
    ``cmd`` (N, K) (in CIELAB units of the photo floor, so 1 where the layouts agree)."""
    n = model.n_pixels
    if model.layout_sd is None:
        return np.ones(cmd.shape + (3,))
    sd = np.stack([np.stack([np.interp(cmd[i], model.grid_mm, model.layout_sd[i, :, c])
                             for c in range(3)], axis=-1) for i in range(n)])
    return PHOTO_LAB_SD / np.sqrt(sd ** 2 + PHOTO_LAB_SD ** 2)


def fit_variation(model: PixelColourModel, commanded_mm: NDArray, measured_lab: NDArray,
                  ccm: NDArray | None = None, *, rounds: int = 4) -> VariationFit:
    """Fit each pixel's length offset and green and yellow gains to its photographed colours.

    ``commanded_mm`` (K,) or (N, K): the lengths the test patterns drove the pixels to;
    ``measured_lab`` (N, K, 3): each pixel's measured CIELAB at them (through the camera's
    colour chain); ``ccm``: the camera's colour correction applied to the model's colours
    (ProPhoto, scale included). Per pixel, least squares on the CIELAB residuals
    (:func:`scipy.optimize.least_squares`, trust region reflective within
    +-:data:`OFFSET_LIMIT_MM` and :data:`GAIN_RANGE`).

    What all pixels share is fitted once for the display, not per pixel: a colour chain a few
    dE00 off (a checker's colour correction typically is) would otherwise bend every pixel's
    gains its own way (on a simulated 4 x 8 display with a 3 dE00 chain, the green gains'
    correlation with the truth fell to 0.66). ``rounds`` > 1 alternates the pixels' fits with
    a display-wide colour balance, one gain per channel of linear ProPhoto (least squares of
    the photos on the model's colours; a full 3 x 3 is ill-determined by colours that all lie
    between yellow and green), and holds the gains' geometric mean over the display at 1: the
    gains are then each pixel's departure from the display's mean pixel, and a uniform change
    (fading of the whole display, or the camera) shows in ``colour`` instead. Where the
    model sees neighbours' grass in a quad (:attr:`PixelColourModel.neighbours`), each
    round holds a pixel's neighbours at the gains of the round before (the first at the
    model pixel's): a Jacobi iteration of the display's coupled fit."""
    from grassd.calib.colour_spaces import lab_to_prophoto

    meas = np.asarray(measured_lab, dtype=np.float64)
    cmd = np.broadcast_to(np.asarray(commanded_mm, dtype=np.float64), meas.shape[:2])
    base = np.eye(3) if ccm is None else np.asarray(ccm, dtype=np.float64)
    colour = np.eye(3)
    rms0 = None
    est = DisplayVariation.none(model.n_pixels)
    for k in range(max(1, rounds)):
        est, rms, first = _fit_pixels(model, cmd, meas, colour @ base, est)
        rms0 = first if rms0 is None else rms0
        if rounds <= 1:
            break
        for g in (est.green_gain, est.yellow_gain):
            g /= np.exp(np.mean(np.log(g)))
        if k == rounds - 1:
            break
        pred = (rec709_to_prophoto(np.clip(model.rgb(cmd, est), 0.0, None))
                @ base.T).reshape(-1, 3)
        seen = lab_to_prophoto(meas).reshape(-1, 3)
        colour = np.diag((pred * seen).sum(axis=0) / (pred * pred).sum(axis=0))
    return VariationFit(est, rms, rms0, colour)


def corrected_commands(viewers: Sequence[PixelColourModel], weights: Sequence[float],
                       variation: DisplayVariation, nominal_mm: NDArray,
                       step_mm: float = 0.05) -> NDArray[np.float64]:
    """(N, L) the length to command each pixel so that it looks, to the viewers, like the model
    pixel at each of ``nominal_mm`` (L,) lengths.

    For pixel p and nominal length x: the command c minimising the viewers' weighted mean
    CIEDE2000 between pixel p as it is (``variation``: gains and offset) commanded to c and the
    model pixel at x, both seen from that viewer (``viewers[w]``: every pixel's model from
    viewer w; ``weights``: the viewers' weights). Searched on a ``step_mm`` grid over the
    mechanism's range; the result is made non-decreasing in x (a table never folds back).

    What a length cannot correct: a real pixel's own tuft layout moves its colour off the
    model's curve, not along it (on the simulated 4 x 8 display the layouts alone leave a worst
    pixel pair of about 2.5 dE00 at mid level, with the true variation corrected exactly)."""
    cmd = np.arange(viewers[0].grid_mm[0], viewers[0].grid_mm[-1] + step_mm / 2, step_mm)
    nominal = np.asarray(nominal_mm, dtype=np.float64)
    none = DisplayVariation.none(variation.n_pixels)
    w = np.asarray(weights, dtype=np.float64) / float(np.sum(weights))
    cost = np.zeros((variation.n_pixels, len(nominal), len(cmd)))
    for model, wk in zip(viewers, w, strict=True):
        target = lab_of(model.rgb(nominal, none))  # (N, L, 3)
        actual = lab_of(model.rgb(cmd, variation))  # (N, C, 3)
        cost += wk * delta_E(target[:, :, None, :], actual[:, None, :, :], method="CIE 2000")
    best = cmd[np.argmin(cost, axis=2)]
    return np.maximum.accumulate(best, axis=1)
