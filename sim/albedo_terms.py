"""Radiance as a polynomial in the materials: the terms a path tracer records once.

With interreflections, the radiance a camera sees is a polynomial in the surfaces' reflectances
whose coefficients a path tracer can record (Ben-Artzi, Egan, Durand, Ramamoorthi 2008, "A
Precomputed Polynomial Representation for Interactive BRDF Editing with Global Illumination",
ACM TOG 27(2)). In the grass pixel each surface reflects ``(1 - ks) * albedo * cos / pi`` (the
Lambertian lobe of its material) plus ``ks * (n + 2) / 2pi * cos^n * cos`` (the glossy lobe,
achromatic, the same on every surface). A path with vertices on materials ``m1 .. mk`` therefore
carries, per colour channel, a sum of products of the symbols

* ``D_m = (1 - ks) * albedo_m[c]`` for the four materials (yellow, green, base, cavity), and
* ``S = ks`` for the glossy lobe,

one factor per vertex, times a geometric weight that depends on the lobe's shape (smoothness)
and the geometry (lengths, splay, layout) but not on the symbols. The renderer's recording mode
(:meth:`grassd.sim.renderer.Renderer.albedo_terms`) samples paths with one reference material,
splits every vertex's reflectance into its two lobes, and sums each path's weights per monomial.
For Lambertian surfaces the paths do not depend on the albedos, so the polynomial gives, for the
same random numbers, exactly what tracing other albedos would. With a glossy lobe the lobe
choice and the MIS weights follow the reference, so another albedo or ``ks`` is an unbiased
reweighting of the reference's paths (importance sampling; the cosine lobe covers the
hemisphere), noisier the further it is from the reference. Up to three vertices carry reflectance
(``max_bounces <= 3``), so the monomials have degree 0..3 in 5 symbols: 56 of them.

Units: albedos linear Rec.709 in [0, 1]; coefficients in the radiance units of the scaled
environment (nits) per unit monomial.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from grassd.sim.errors import SceneError

#: Symbols of the polynomial: the four materials' diffuse reflectances, then the glossy ``ks``.
SYMBOLS: tuple[str, ...] = ("yellow", "green", "base", "cavity", "specular")
N_SYMBOLS: int = len(SYMBOLS)
SPECULAR: int = 4  #: index of the glossy symbol
MAX_DEGREE: int = 3  #: vertices that carry reflectance (max_bounces <= 3)
CODE_BASE: int = 4  #: a monomial's code: sum of count_s * 4**s (counts 0..3)


def monomials() -> NDArray[np.int64]:
    """(56, 5) exponent vectors of every monomial of degree 0..3 in the 5 symbols, ordered by
    degree, then lexicographically; row 0 is the constant (a camera ray that meets nothing).

    >>> monomials().shape
    (56, 5)
    """
    rows = [e for e in itertools.product(range(MAX_DEGREE + 1), repeat=N_SYMBOLS)
            if sum(e) <= MAX_DEGREE]
    rows.sort(key=lambda e: (sum(e), tuple(-v for v in e)))
    return np.array(rows, dtype=np.int64)


MONOMIALS: NDArray[np.int64] = monomials()
N_MONOMIALS: int = len(MONOMIALS)


def code_table() -> NDArray[np.int32]:
    """(4**5,) index of each monomial by its code ``sum(count_s * 4**s)``; -1 for codes of
    degree above 3 (a kernel adds ``4**s`` to a term's code for each factor of symbol s)."""
    table = np.full(CODE_BASE ** N_SYMBOLS, -1, dtype=np.int32)
    codes = MONOMIALS @ (CODE_BASE ** np.arange(N_SYMBOLS))
    table[codes] = np.arange(N_MONOMIALS, dtype=np.int32)
    return table


def symbol_values(albedo_linear: NDArray[np.float64], specular: float | NDArray[np.float64]
                  ) -> NDArray[np.float64]:
    """(..., 5, 3) values of the symbols per channel for albedos ``(..., 4, 3)`` (linear, rows
    in material order) and glossy reflectance ``specular`` (scalar or ``(...)``)."""
    a = np.asarray(albedo_linear, dtype=np.float64)
    ks = np.asarray(specular, dtype=np.float64)[..., None, None]
    diffuse = (1.0 - ks) * a
    glossy = np.broadcast_to(ks, a.shape[:-2] + (1, 3))
    return np.concatenate([diffuse, glossy], axis=-2)


def monomial_values(albedo_linear: NDArray[np.float64], specular: float | NDArray[np.float64]
                    ) -> NDArray[np.float64]:
    """(..., 56, 3) value of each monomial per channel (see :func:`symbol_values`)."""
    v = symbol_values(albedo_linear, specular)  # (..., 5, 3)
    powers = v[..., None, :, :] ** MONOMIALS[:, :, None]  # (..., 56, 5, 3)
    return powers.prod(axis=-2)


@dataclass(frozen=True)
class AlbedoTerms:
    """One viewpoint's radiance at several green lengths as polynomials in the materials.

    ``coefficients`` (R, n, 56, 3): per replicate, length, monomial (:data:`MONOMIALS`) and
    channel, the mean over the measurement quad of the paths' weights, in nits per unit
    monomial; the radiance is ``sum_m coefficients[..., m, c] * monomial_m[c]``
    (:meth:`radiance`). Replicates are independent, with the same random numbers across
    lengths (common random numbers). ``glossy``: whether the glossy lobe was recorded (without
    it, only ``specular = 0`` can be evaluated). ``seconds``: compile, trace, total.
    """

    viewpoint: object
    lengths_mm: NDArray[np.float64]
    coefficients: NDArray[np.float64]
    glossy: bool
    samples_per_length: int
    seconds: dict[str, float] = field(default_factory=dict)

    def radiance(self, albedo_linear: NDArray[np.float64], specular: float = 0.0
                 ) -> NDArray[np.float64]:
        """(R, n, 3) replicate radiance (linear Rec.709, nits) for albedos (4, 3) linear in
        material order (yellow, green, base, cavity) and glossy reflectance ``specular``."""
        if specular and not self.glossy:
            raise SceneError("these terms were recorded without the glossy lobe; record with "
                             "glossy=True to evaluate a specular reflectance")
        mono = monomial_values(albedo_linear, specular)
        return np.einsum("rnmc,mc->rnc", self.coefficients, mono)
