"""Colour-correction matrix: map virtual (rendered) checker colours onto real (captured) ones.

The paper fits a plain 3x3 matrix M by multivariate least squares so that, for the 24 patches
of a colour checker in ProPhoto linear RGB, ``real ~= M . virtual``. Beside it we offer the
root-polynomial correction of Finlayson, Mackiewicz & Hurlbert (2015), "Color Correction Using
Root-Polynomial Regression", IEEE TIP 24(5), through colour-science's
``matrix_colour_correction(method="Finlayson 2015")``; being homogeneous of degree one it is, like
the 3x3, independent of exposure. Every fit reports its per-patch, mean and maximum CIEDE2000
residual (CIELAB with the D50 ProPhoto white), so both can be compared on the same patches.

A fitting residual flatters the form with more terms (13 coefficients per channel fitted to 24
patches). Every fit therefore also carries its *leave-one-out* error: each patch predicted by the
same form fitted to the other N - 1 patches (:func:`leave_one_out_de00`), which is what a
correction does to a colour it was not fitted to. :func:`select_ccm` (``fit_ccm(...,
method="auto")``) fits every candidate form of :data:`CCM_FORMS` (the 3x3 and the root-polynomial
corrections of degree 2 and 3) and keeps the one of lowest leave-one-out mean CIEDE2000; reports
print :attr:`ColourCorrection.reported_de00` (the leave-one-out mean / max where known).

Every form here is a linear least-squares fit of the channels on a fixed expansion of the input
(the 3 channels, or Finlayson's root-polynomial terms), so the leave-one-out predictions come in
closed form from the hat matrix ``H = X (X^T X)^+ X^T`` of the expansion ``X``:
``y_loo_i = y_i - (y_i - yhat_i) / (1 - H_ii)`` (Allen 1974, "The relationship between variable
selection and data augmentation and a method for prediction", Technometrics 16(1); Hastie,
Tibshirani & Friedman, *The Elements of Statistical Learning*, 2nd ed., eq. 7.52), with no refit.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from grassd.calib.array_checks import as_float_array, same_shape
from grassd.calib.colour_spaces import prophoto_to_lab
from grassd.calib.errors import ShapeError, UnknownMethodError


@dataclass(frozen=True)
class CCMScore:
    """How one candidate form did on the patches (all CIEDE2000, D50 CIELAB).

    Attributes:
        form: the form's name in :data:`CCM_FORMS` ("3x3", "root-polynomial-2", ...).
        loo_mean_de00, loo_max_de00: leave-one-out mean and maximum.
        fit_mean_de00, fit_max_de00: fitting residual mean and maximum.
    """

    form: str
    loo_mean_de00: float
    loo_max_de00: float
    fit_mean_de00: float
    fit_max_de00: float


@dataclass(frozen=True, eq=False)
class ColourCorrection:
    """A fitted colour correction, its residuals on the patches it was fitted to and its
    leave-one-out errors on them.

    Attributes:
        method: "3x3" (the paper's matrix) or "root-polynomial" (Finlayson 2015).
        matrix: (3, 3) for "3x3"; (3, terms) for "root-polynomial".
        degree: root-polynomial degree (1 for "3x3").
        residual_de00: (N,) CIEDE2000 between corrected virtual and real patches.
        mean_de00, max_de00: mean and maximum of ``residual_de00`` (the fitting residual).
        loo_de00: (N,) CIEDE2000 of each patch predicted by the same form fitted to the other
            patches; None when not computed (a matrix read back from a previous run).
        loo_mean_de00, loo_max_de00: mean and maximum of ``loo_de00`` (NaN when unknown).
        candidates: the scores of every form compared when the form was chosen by
            :func:`select_ccm`, best first; empty for a single fit.
    """

    method: str
    matrix: NDArray[np.float64]
    degree: int
    residual_de00: NDArray[np.float64]
    mean_de00: float
    max_de00: float
    loo_de00: NDArray[np.float64] | None = None
    loo_mean_de00: float = float("nan")
    loo_max_de00: float = float("nan")
    candidates: tuple[CCMScore, ...] = field(default=())

    @property
    def form(self) -> str:
        """The form's name in :data:`CCM_FORMS`: "3x3" or "root-polynomial-<degree>"."""
        return "3x3" if self.method == "3x3" else f"{self.method}-{self.degree}"

    @property
    def reported_de00(self) -> tuple[float, float]:
        """(mean, max) CIEDE2000 a report should print: the leave-one-out figures where known,
        else the fitting residual's."""
        if np.isfinite(self.loo_mean_de00):
            return self.loo_mean_de00, self.loo_max_de00
        return self.mean_de00, self.max_de00

    def apply(self, rgb: ArrayLike) -> NDArray[np.float64]:
        """Correct ProPhoto linear RGB (..., 3) from the virtual to the real camera."""
        arr = as_float_array(rgb, "rgb", last_dim=3)
        return _APPLY[self.method](arr, self.matrix, self.degree)

    def to_json(self) -> dict[str, object]:
        """What a later run needs to apply it again: ``method``, ``degree`` and ``matrix``
        (nested lists); :meth:`from_json` reads it back."""
        return {"method": self.method, "degree": self.degree, "matrix": self.matrix.tolist()}

    @classmethod
    def from_json(cls, d: object) -> ColourCorrection:
        """The correction :meth:`to_json` wrote, or a bare (3, 3) matrix (nested lists: the
        form earlier versions kept), with no residuals (NaN: not known).

        >>> ColourCorrection.from_json([[1, 0, 0], [0, 1, 0], [0, 0, 1]]).form
        '3x3'

        Raises:
            UnknownMethodError: an unknown ``method``.
            ShapeError: a matrix of the wrong shape for its form.
        """
        method, degree, matrix = ("3x3", 1, d) if not isinstance(d, dict) else (
            d.get("method"), d.get("degree", 1), d.get("matrix"))
        if method not in _APPLY:
            raise UnknownMethodError(f"unknown colour-correction method {method!r}; "
                                     f"use one of {', '.join(_APPLY)}")
        m = as_float_array(matrix, "matrix")
        terms = 3 if method == "3x3" else _TERMS.get(int(degree), -1)
        if m.shape != (3, terms):
            raise ShapeError(f"a {method} correction of degree {degree} needs a (3, {terms}) "
                             f"matrix; got {m.shape}")
        nan = float("nan")
        return cls(str(method), m, int(degree), np.zeros(0), nan, nan)

    def scaled(self, s: float) -> ColourCorrection:
        """The same correction applied to input scaled by ``s``: ``c.scaled(s).apply(x) ==
        c.apply(s * x)``. Every form here is homogeneous of degree one, so this is the matrix
        times ``s`` (the residuals are the fit's, unchanged)."""
        return ColourCorrection(self.method, self.matrix * float(s), self.degree,
                                self.residual_de00, self.mean_de00, self.max_de00, self.loo_de00,
                                self.loo_mean_de00, self.loo_max_de00, self.candidates)


def residual_de00(predicted: ArrayLike, real: ArrayLike) -> NDArray[np.float64]:
    """Per-patch CIEDE2000 between two ProPhoto linear RGB arrays (N, 3), via D50 CIELAB."""
    import colour  # on first use: see grassd.calib.colour_spaces

    return colour.delta_E(prophoto_to_lab(predicted), prophoto_to_lab(real), method="CIE 2000")


def _expand(rgb: NDArray, method: str, degree: int) -> NDArray[np.float64]:
    """The terms (N, p) each channel of a ``method`` correction is a linear combination of."""
    if method == "3x3":
        return rgb
    import colour  # on first use: see grassd.calib.colour_spaces

    return np.asarray(colour.characterisation.polynomial_expansion_Finlayson2015(
        rgb, degree, root_polynomial_expansion=True), dtype=np.float64)


def leave_one_out_rgb(virtual: ArrayLike, real: ArrayLike, method: str = "3x3", *,
                      degree: int = 2) -> NDArray[np.float64]:
    """(N, 3) prediction of each real patch by the ``method`` correction fitted to the other
    N - 1 patches (closed form from the hat matrix, see the module docstring; no refit).

    A patch whose leverage is 1 (the others do not determine the fit at it) predicts NaN.

    >>> rgb = np.random.default_rng(1).uniform(0.05, 0.9, (24, 3))
    >>> m = np.array([[1.1, 0.05, 0.0], [0.02, 0.95, 0.03], [0.0, 0.1, 0.9]])
    >>> bool(np.allclose(leave_one_out_rgb(rgb, rgb @ m.T), rgb @ m.T))
    True
    """
    v = as_float_array(virtual, "virtual", last_dim=3, ndim=2, non_negative=True)
    r = as_float_array(real, "real", last_dim=3, ndim=2, non_negative=True)
    same_shape(v, r, "virtual", "real")
    x = _expand(v, method, 1 if method == "3x3" else int(degree))
    u, sv, _ = np.linalg.svd(x, full_matrices=False)
    keep = sv > sv[0] * max(x.shape) * np.finfo(np.float64).eps
    u = u[:, keep]
    leverage = np.einsum("ij,ij->i", u, u)
    fitted = u @ (u.T @ r)
    with np.errstate(divide="ignore", invalid="ignore"):
        out = r - (r - fitted) / (1.0 - leverage)[:, None]
    out[leverage > 1.0 - 1e-9] = np.nan
    return out


def leave_one_out_de00(virtual: ArrayLike, real: ArrayLike, method: str = "3x3", *,
                       degree: int = 2) -> NDArray[np.float64]:
    """(N,) CIEDE2000 between each real patch and its leave-one-out prediction
    (:func:`leave_one_out_rgb`, clipped at 0 as :func:`fit_ccm` clips its predictions);
    infinite where the other patches do not determine the fit."""
    pred = leave_one_out_rgb(virtual, real, method, degree=degree)
    r = np.asarray(real, dtype=np.float64)
    bad = ~np.isfinite(pred).all(axis=1)
    de = residual_de00(np.clip(np.where(bad[:, None], r, pred), 0.0, None), r)
    return np.where(bad, np.inf, de)


def _fit_3x3(virtual: NDArray, real: NDArray, degree: int) -> NDArray[np.float64]:
    # real_i = M virtual_i  <=>  real = virtual @ M.T ; least squares column by column.
    m_t, *_ = np.linalg.lstsq(virtual, real, rcond=None)
    return m_t.T


def _apply_3x3(rgb: NDArray, matrix: NDArray, degree: int) -> NDArray[np.float64]:
    return rgb @ matrix.T


def _fit_root_poly(virtual: NDArray, real: NDArray, degree: int) -> NDArray[np.float64]:
    import colour  # on first use: see grassd.calib.colour_spaces

    return np.asarray(
        colour.characterisation.matrix_colour_correction(
            virtual, real, method="Finlayson 2015", degree=degree, root_polynomial_expansion=True
        ),
        dtype=np.float64,
    )


def _apply_root_poly(rgb: NDArray, matrix: NDArray, degree: int) -> NDArray[np.float64]:
    import colour  # on first use: see grassd.calib.colour_spaces

    return np.asarray(
        colour.characterisation.apply_matrix_colour_correction_Finlayson2015(
            rgb, matrix, degree=degree, root_polynomial_expansion=True
        ),
        dtype=np.float64,
    )


#: Method name -> fitting function (virtual (N,3), real (N,3), degree) -> matrix.
CCM_METHODS: dict[str, Callable[[NDArray, NDArray, int], NDArray[np.float64]]] = {
    "3x3": _fit_3x3,
    "root-polynomial": _fit_root_poly,
}
_APPLY: dict[str, Callable[[NDArray, NDArray, int], NDArray[np.float64]]] = {
    "3x3": _apply_3x3,
    "root-polynomial": _apply_root_poly,
}


#: Candidate forms of :func:`select_ccm`, simplest first: name -> (method, degree).
CCM_FORMS: dict[str, tuple[str, int]] = {
    "3x3": ("3x3", 1),
    "root-polynomial-2": ("root-polynomial", 2),
    "root-polynomial-3": ("root-polynomial", 3),
}
#: Terms per channel of a root-polynomial expansion of each degree (Finlayson 2015, table 1).
_TERMS: dict[int, int] = {1: 3, 2: 6, 3: 13, 4: 22}


def fit_ccm(
    virtual: ArrayLike, real: ArrayLike, method: str = "3x3", *, degree: int = 2
) -> ColourCorrection:
    """Fit ``real ~= correction(virtual)`` over checker patches in ProPhoto linear RGB.

    Args:
        virtual: (N, 3) ProPhoto linear RGB of the rendered patches (N >= 3; 24 for a checker).
        real: (N, 3) ProPhoto linear RGB of the captured patches, same order.
        method: "3x3" (plain least-squares matrix, the paper's), "root-polynomial", or "auto"
            (the form of :data:`CCM_FORMS` of lowest leave-one-out mean CIEDE2000:
            :func:`select_ccm`).
        degree: root-polynomial degree (2 or 3); ignored for "3x3" and "auto".

    Returns:
        The fit with its per-patch / mean / max CIEDE2000 residuals and its leave-one-out
        errors (``loo_de00``, ``loo_mean_de00``, ``loo_max_de00``; infinite when N is the
        number of terms, leaving nothing to predict a patch from).

    >>> rgb = np.random.default_rng(0).uniform(0.05, 0.9, (24, 3))
    >>> M = np.array([[1.1, 0.05, 0.0], [0.02, 0.95, 0.03], [0.0, 0.1, 0.9]])
    >>> fit = fit_ccm(rgb, rgb @ M.T)
    >>> bool(np.allclose(fit.matrix, M)), fit.max_de00 < 1e-9
    (True, True)
    """
    if method == "auto":
        return select_ccm(virtual, real)
    if method not in CCM_METHODS:
        raise UnknownMethodError(
            f"unknown colour-correction method {method!r}; use one of "
            f"{', '.join(CCM_METHODS)} or auto"
        )
    v = as_float_array(virtual, "virtual", last_dim=3, ndim=2, non_negative=True)
    r = as_float_array(real, "real", last_dim=3, ndim=2, non_negative=True)
    same_shape(v, r, "virtual", "real")
    deg = 1 if method == "3x3" else int(degree)
    n_terms = _TERMS.get(deg) if method != "3x3" else 3
    if n_terms is None:
        raise UnknownMethodError(f"root-polynomial degree must be 1..4; got {degree}")
    if v.shape[0] < n_terms:
        raise ShapeError(
            f"a {method} fit of degree {deg} needs at least {n_terms} patches; got {v.shape[0]}"
        )
    if np.linalg.matrix_rank(v) < 3:
        raise ShapeError(
            "the virtual patches do not span three colour dimensions (all grey or collinear); "
            "fit on a chart with chromatic patches"
        )
    matrix = CCM_METHODS[method](v, r, deg)
    predicted = np.clip(_APPLY[method](v, matrix, deg), 0.0, None)
    res = residual_de00(predicted, r)
    loo = leave_one_out_de00(v, r, method, degree=deg)
    return ColourCorrection(
        method=method,
        matrix=matrix,
        degree=deg,
        residual_de00=res,
        mean_de00=float(res.mean()),
        max_de00=float(res.max()),
        loo_de00=loo,
        loo_mean_de00=float(loo.mean()),
        loo_max_de00=float(loo.max()),
    )


def compare_ccm_forms(virtual: ArrayLike, real: ArrayLike,
                      forms: Sequence[str] = tuple(CCM_FORMS)) -> dict[str, ColourCorrection]:
    """Fit every form named in ``forms`` (keys of :data:`CCM_FORMS`) that the patches can
    determine with one to spare for leave-one-out: {form: fit}, in the order given.

    Raises:
        UnknownMethodError: a name not in :data:`CCM_FORMS`.
        ShapeError: no form fits so few patches (or as :func:`fit_ccm`).
    """
    unknown = [f for f in forms if f not in CCM_FORMS]
    if unknown or not forms:
        raise UnknownMethodError(f"unknown colour-correction form(s) {unknown or list(forms)}; "
                                 f"use some of {', '.join(CCM_FORMS)}")
    n = np.shape(virtual)[0] if np.ndim(virtual) == 2 else 0
    usable = [f for f in forms if n > _TERMS[CCM_FORMS[f][1]]]
    if not usable:
        need = min(_TERMS[CCM_FORMS[f][1]] for f in forms) + 1
        raise ShapeError(f"choosing a colour correction by leave-one-out error needs at least "
                         f"{need} patches; got {n}")
    return {f: fit_ccm(virtual, real, CCM_FORMS[f][0], degree=CCM_FORMS[f][1]) for f in usable}


def select_ccm(virtual: ArrayLike, real: ArrayLike,
               forms: Sequence[str] = tuple(CCM_FORMS)) -> ColourCorrection:
    """The correction of lowest leave-one-out mean CIEDE2000 among ``forms``.

    Each form of :data:`CCM_FORMS` that the patches determine with one to spare is fitted
    (:func:`compare_ccm_forms`); the one whose patches, each predicted from the others, are
    nearest on average wins; a tie (within 1e-9 dE00) goes to the simpler form. The result
    carries every candidate's :class:`CCMScore`, best first, in ``candidates``. Forms:
    the 3x3 and Finlayson, Mackiewicz & Hurlbert (2015) root-polynomial of degree 2 and 3.

    >>> rgb = np.random.default_rng(0).uniform(0.05, 0.9, (24, 3))
    >>> fit = select_ccm(rgb, rgb ** 1.2 * rgb.sum(1, keepdims=True) ** -0.2)
    >>> fit.form != "3x3", fit.candidates[0].form == fit.form
    (True, True)
    """
    fits = compare_ccm_forms(virtual, real, forms)
    scores = [CCMScore(f, c.loo_mean_de00, c.loo_max_de00, c.mean_de00, c.max_de00)
              for f, c in fits.items()]
    order = sorted(range(len(scores)), key=lambda i: (round(scores[i].loo_mean_de00, 9), i))
    best = fits[scores[order[0]].form]
    return ColourCorrection(best.method, best.matrix, best.degree, best.residual_de00,
                            best.mean_de00, best.max_de00, best.loo_de00, best.loo_mean_de00,
                            best.loo_max_de00, tuple(scores[i] for i in order))


def compare_ccm_methods(
    virtual: ArrayLike, real: ArrayLike, *, degree: int = 2
) -> dict[str, ColourCorrection]:
    """Fit both the paper's 3x3 and the root-polynomial correction; {method: fit}."""
    return {m: fit_ccm(virtual, real, m, degree=degree) for m in CCM_METHODS}
