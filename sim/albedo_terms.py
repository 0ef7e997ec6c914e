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
hemisphere), noisier the further it is from the reference. With ``max_bounces <= 3`` at most
three vertices carry reflectance, so the monomials have degree 0..3 in 5 symbols: 56 of them
(:data:`MAX_DEGREE`, the shallow recording).

Deeper paths (``max_bounces`` above 3, Russian roulette ending them) are recorded exactly up to
degree ``degree`` (:data:`TERM_DEGREE` by default: ``C(degree + 5, 5)`` monomials, 1287 for 8),
and a path's vertices beyond it are a tail term: each further vertex multiplies the term by the
reference's own reflectance of its material (``(1 - ks) albedo`` and ``ks`` of the lobes, as
sampled), not by a symbol, so the term stays on the monomial of its first ``degree`` vertices.
Evaluated at the reference the polynomial is exact at every depth (the same paths, the same
weights); at other materials only the tail's vertices keep the reference's reflectance, an error
of at most the tail's share of the radiance times the relative change of its further vertices'
reflectances (docs/renderer/measurements.md measures both). A glossy path keeps both lobes as
terms while it has at most :data:`TERM_SLOTS` of them; after that each term takes one lobe at
random, with probability in proportion to the two lobes' weights and divided by it (unbiased
for any ``ks``, as the reference's lobe choice is).

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
MAX_DEGREE: int = 3  #: vertices that carry reflectance in a shallow recording (max_bounces <= 3)
CODE_BASE: int = 4  #: a shallow monomial's code: sum of count_s * 4**s (counts 0..3)
TERM_DEGREE: int = 8  #: degree recorded exactly for deeper paths (their tail beyond it: above)
DEEP_CODE_BASE: int = 16  #: a deep monomial's code: sum of count_s * 16**s (counts 0..15)
MAX_TERM_DEGREE: int = DEEP_CODE_BASE - 1  #: the highest degree a deep code holds
TERM_SLOTS: int = 8  #: terms a glossy path keeps per lobe split before choosing lobes at random


def monomials(degree: int = MAX_DEGREE) -> NDArray[np.int64]:
    """(C(degree + 5, 5), 5) exponent vectors of every monomial of degree 0..``degree`` in the
    5 symbols, ordered by degree, then lexicographically (so the first 56 rows of any degree
    >= 3 are those of degree 3); row 0 is the constant (a camera ray that meets nothing).

    >>> monomials().shape, monomials(8).shape
    ((56, 5), (1287, 5))
    """
    if not 0 <= degree <= MAX_TERM_DEGREE:
        raise SceneError(f"a polynomial's degree must be in 0..{MAX_TERM_DEGREE}, got {degree}")
    rows = [e for e in itertools.product(range(degree + 1), repeat=N_SYMBOLS)
            if sum(e) <= degree]
    rows.sort(key=lambda e: (sum(e), tuple(-v for v in e)))
    return np.array(rows, dtype=np.int64)


MONOMIALS: NDArray[np.int64] = monomials()
N_MONOMIALS: int = len(MONOMIALS)
_MONOMIALS: dict[int, NDArray[np.int64]] = {MAX_DEGREE: MONOMIALS}


def monomials_of(degree: int) -> NDArray[np.int64]:
    """:func:`monomials` of ``degree``, computed once (read-only)."""
    if degree not in _MONOMIALS:
        rows = monomials(degree)
        rows.setflags(write=False)
        _MONOMIALS[degree] = rows
    return _MONOMIALS[degree]


def n_monomials(degree: int = MAX_DEGREE) -> int:
    """Number of monomials of degree 0..``degree`` in the 5 symbols: ``C(degree + 5, 5)``."""
    return len(monomials_of(degree))


def code_table(degree: int = MAX_DEGREE) -> NDArray[np.int32]:
    """Index of each monomial by its code: for ``degree`` 3 (the shallow recording) a (4**5,)
    table of codes ``sum(count_s * 4**s)``, else a (16**5,) table of codes
    ``sum(count_s * 16**s)``; -1 for codes of higher degree (a kernel adds ``base**s`` to a
    term's code for each factor of symbol s)."""
    rows = monomials_of(degree)
    base = CODE_BASE if degree <= MAX_DEGREE else DEEP_CODE_BASE
    table = np.full(base ** N_SYMBOLS, -1, dtype=np.int32)
    codes = rows @ (base ** np.arange(N_SYMBOLS))
    table[codes] = np.arange(len(rows), dtype=np.int32)
    return table


def symbol_values(albedo_linear: NDArray[np.float64], specular: float | NDArray[np.float64]
                  ) -> NDArray[np.float64]:
    """(..., 5, C) values of the symbols per channel for albedos ``(..., 4, C)`` (linear, rows
    in material order; C = 3 Rec.709 channels, or a reflectance spectrum's C wavelengths) and
    glossy reflectance ``specular`` (scalar or ``(...)``)."""
    a = np.asarray(albedo_linear, dtype=np.float64)
    ks = np.asarray(specular, dtype=np.float64)[..., None, None]
    diffuse = (1.0 - ks) * a
    glossy = np.broadcast_to(ks, a.shape[:-2] + (1, a.shape[-1]))
    return np.concatenate([diffuse, glossy], axis=-2)


def monomial_values(albedo_linear: NDArray[np.float64], specular: float | NDArray[np.float64],
                    degree: int = MAX_DEGREE) -> NDArray[np.float64]:
    """(..., C(degree + 5, 5), C) value of each monomial of :func:`monomials` (``degree``) per
    channel (see :func:`symbol_values`); 56 rows for the default degree 3."""
    v = symbol_values(albedo_linear, specular)  # (..., 5, C)
    rows = monomials_of(degree)
    if degree <= MAX_DEGREE:
        return (v[..., None, :, :] ** rows[:, :, None]).prod(axis=-2)
    powers = v[..., None, :, :] ** np.arange(degree + 1)[:, None, None]  # (..., k, 5, C)
    out = powers[..., rows[:, 0], 0, :]
    for s in range(1, N_SYMBOLS):
        out = out * powers[..., rows[:, s], s, :]
    return out


def check_lobe(glossy: bool, specular: float) -> None:
    """Refuse to evaluate a glossy reflectance ``specular`` on terms recorded without the
    glossy lobe (``glossy`` False): they hold no monomial of ``S``."""
    if specular and not glossy:
        raise SceneError("these terms were recorded without the glossy lobe; record with "
                         "glossy=True to evaluate a specular reflectance")


@dataclass(frozen=True)
class AlbedoTerms:
    """One viewpoint's radiance at several green lengths as polynomials in the materials.

    ``coefficients`` (R, n, M, 3): per replicate, length, monomial (:func:`monomials` of
    ``degree``: M = 56 for degree 3) and channel, the mean over the measurement quad of the
    paths' weights, in nits per unit monomial; the radiance is
    ``sum_m coefficients[..., m, c] * monomial_m[c]`` (:meth:`radiance`;
    :func:`monomial_values` with the same ``degree`` gives the monomials). Replicates are
    independent, with the same random numbers across lengths (common random numbers).
    ``glossy``: whether the glossy lobe was recorded (without it, only ``specular = 0`` can be
    evaluated). ``degree``: the polynomial's; ``tail``: whether vertices beyond it were
    recorded as the tail term (module docstring). ``seconds``: compile, trace, total.
    """

    viewpoint: object
    lengths_mm: NDArray[np.float64]
    coefficients: NDArray[np.float64]
    glossy: bool
    samples_per_length: int
    seconds: dict[str, float] = field(default_factory=dict)
    degree: int = MAX_DEGREE
    tail: bool = False

    def radiance(self, albedo_linear: NDArray[np.float64], specular: float = 0.0
                 ) -> NDArray[np.float64]:
        """(R, n, 3) replicate radiance (linear Rec.709, nits) for albedos (4, 3) linear in
        material order (yellow, green, base, cavity) and glossy reflectance ``specular``."""
        check_lobe(self.glossy, specular)
        mono = monomial_values(albedo_linear, specular, self.degree)
        return np.einsum("rnmc,mc->rnc", self.coefficients, mono)
