"""Whether a measurement's photos are evidence: fresh, of the display state asked, and agreeing
with the correction they produce. A correction is pushed only when every check holds.

The measuring camera is not trusted: it could answer with old photos, with the shots out of
order, or with a photo of another display state, and each would still make "after" look better
than "before". So:

* **Freshness** (:func:`shot_order`): the shots are taken in an order drawn at random for every
  measurement (:mod:`secrets`), one state photographed twice (the *repeat*); a camera cannot know
  which state the display shows at its next shot, and photos kept from an earlier measurement
  come in that measurement's order.
* **The display in its photos**: the photos of the shortest and longest grass must show the
  display (it is located from their difference); when they do not, nothing else is judged.
* **The measurement's own noise** (:func:`photo_noise`): the repeat's two photos differ by the
  camera's noise; the model's own spread (the tuft layouts it averages, ``layout_sd``, or
  :data:`~grassd.daemon.measure.pixel_model.PHOTO_LAB_SD` without it) is added in
  quadrature: ``noise_lab``. Two photos of the repeat that disagree by more than
  :data:`MAX_PHOTO_NOISE_LAB` leave nothing to judge by (and the limits take in no more than
  that: noisy photos cannot widen them).
* **The fit** (:func:`judge`): the median over pixels of each pixel's RMS CIELAB residual must
  stay within :data:`RESIDUAL_FACTOR` x ``noise_lab``; no more than :data:`BOUND_FRACTION` of
  the pixels may have a fitted offset or gain at its bound (a fit pushed there explains photos
  that the display did not make).
* **Every photo of its state**: each shot's median RMS residual against the fitted model at the
  lengths that shot commanded, within :data:`SHOT_FACTOR` x ``noise_lab``: a photo out of order,
  old, or of another state is named. Every photo pulls the fit, so one wrong photo can take
  honest ones past the limit with it: the worst shot is left out and the model fitted again
  without it (:func:`name_mismatches`), until the shots left agree with their fit, so that only
  the culprits are named.
* **Verification**: each photo after the correction against what the fitted model predicts for
  the corrected commands, within the same bound; and only then the uniformity: after below
  before.

Units: CIELAB (D50) residuals as RMS over the three channels ("rms Lab"), lengths mm.
"""

from __future__ import annotations

import secrets
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from enum import Enum
from typing import TYPE_CHECKING, TypedDict

import numpy as np
from numpy.typing import NDArray

from grassd.daemon.core.errors import DaemonError

if TYPE_CHECKING:
    from grassd.daemon.core.calibration.variation import DisplayVariation
    from grassd.daemon.measure.pixel_model import PixelColourModel

#: The fit's median per-pixel residual may be this many times the measurement's noise.
RESIDUAL_FACTOR: float = 4.0
#: A shot's median per-pixel residual may be this many times the measurement's noise.
SHOT_FACTOR: float = 6.0
#: Largest noise (rms Lab) of the repeated shot's two photos that still lets photos be judged
#: (and the most of it the limits below take in: a camera cannot widen them by noise).
MAX_PHOTO_NOISE_LAB: float = 0.5
#: Largest share of pixels whose fitted offset or a gain lies at its bound.
BOUND_FRACTION: float = 0.1
#: How near a bound (share of the offset limit, of a gain bound) counts as at it.
BOUND_MARGIN: float = 0.02
#: Most shots left out, one fit each, to tell wrong photos from the honest ones their fit
#: pulled (:func:`name_mismatches`); beyond them every shot still over the limit is named.
MOST_REFITS: int = 3

#: A fit of the shots kept, ``refit(kept)`` with ``kept`` (K,) bool over the shots judged:
#: the (N, K, 3) CIELAB it predicts for every one of them.
Refit = Callable[[NDArray[np.bool_]], NDArray[np.float64]]


class Refusal(Enum):
    """Why a measurement's correction is not pushed."""

    DISPLAY_NOT_FOUND = "display not found"
    PHOTO_NOISE = "photo noise"
    FIT_RESIDUAL = "fit residual"
    OFFSETS_AT_BOUND = "offsets at bound"
    SHOT_MISMATCH = "shot mismatch"
    VERIFICATION = "verification"
    NOT_MORE_UNIFORM = "not more uniform"


class FindingJson(TypedDict):
    """A :class:`Finding` as the measurement's report holds it (``kind`` a :class:`Refusal`
    value)."""

    kind: str
    detail: str
    shots: list[str]


class LimitsJson(TypedDict):
    """The limits the evidence was judged by (rms Lab; ``at_bound`` a share of the pixels)."""

    fit_rms_lab: float
    shot_rms_lab: float
    at_bound: float


class EvidenceSummaryJson(TypedDict):
    """Whether the photos were evidence, the shots as taken and the failed checks: all a
    measurement's report holds of photos refused before they could be judged."""

    accepted: bool
    order: list[str]
    findings: list[FindingJson]


class EvidenceJson(EvidenceSummaryJson):
    """An :class:`Evidence` as the measurement's report holds it (``evidence``)."""

    noise_lab: float
    photo_noise_lab: float
    model_noise_lab: float
    fit_rms_lab: float
    limits: LimitsJson
    shot_rms_lab: dict[str, float]
    at_bound: int


@dataclass(frozen=True)
class Finding:
    """One failed check: its ``kind``, what was seen (``detail``, for the user) and the
    ``shots`` it concerns (names; empty for the whole fit)."""

    kind: Refusal
    detail: str
    shots: tuple[str, ...] = ()

    def to_json(self) -> FindingJson:
        """The finding as the report holds it."""
        return {"kind": self.kind.value, "detail": self.detail, "shots": list(self.shots)}


@dataclass(frozen=True)
class Evidence:
    """What the checks found (module docstring). ``noise_lab``: the measurement's noise (rms
    Lab), from the repeat's photos (``photo_noise_lab``) and the model's spread
    (``model_noise_lab``); ``fit_rms_lab``: the fit's median per-pixel residual;
    ``shot_rms_lab``: per shot, its median per-pixel residual against its own state;
    ``at_bound``: pixels with a fitted value at its bound; ``order``: the shots as taken;
    ``findings``: the failed checks (none: the correction may be pushed)."""

    noise_lab: float
    photo_noise_lab: float
    model_noise_lab: float
    fit_rms_lab: float
    shot_rms_lab: dict[str, float]
    at_bound: int
    order: tuple[str, ...]
    findings: tuple[Finding, ...] = field(default_factory=tuple)

    @property
    def accepted(self) -> bool:
        """Every check held."""
        return not self.findings

    def refusals(self) -> tuple[Refusal, ...]:
        """The kinds of the failed checks, in the order found."""
        return tuple(f.kind for f in self.findings)

    def reason(self) -> str:
        """The failed checks in words (empty when accepted)."""
        return "; ".join(f.detail for f in self.findings)

    def with_finding(self, finding: Finding) -> Evidence:
        """These findings and ``finding``."""
        from dataclasses import replace

        return replace(self, findings=(*self.findings, finding))

    def to_json(self) -> EvidenceJson:
        """The evidence as the measurement's report holds it (``evidence``)."""
        return {"accepted": self.accepted, "noise_lab": round(self.noise_lab, 4),
                "photo_noise_lab": round(self.photo_noise_lab, 4),
                "model_noise_lab": round(self.model_noise_lab, 4),
                "fit_rms_lab": round(self.fit_rms_lab, 4),
                "limits": {"fit_rms_lab": round(RESIDUAL_FACTOR * self.noise_lab, 4),
                           "shot_rms_lab": round(SHOT_FACTOR * self.noise_lab, 4),
                           "at_bound": BOUND_FRACTION},
                "shot_rms_lab": {k: round(v, 4) for k, v in self.shot_rms_lab.items()},
                "at_bound": self.at_bound, "order": list(self.order),
                "findings": [f.to_json() for f in self.findings]}


class PhotosRefused(DaemonError):
    """The photos cannot even be analysed as the display's (``finding`` says why); raised
    inside a measurement, which ends with that refusal."""

    def __init__(self, finding: Finding) -> None:
        super().__init__(finding.detail)
        self.finding = finding


def shot_order(names: Sequence[str], repeat_of: Sequence[str] | None = None,
               rng: secrets.SystemRandom | None = None) -> tuple[list[str], str | None]:
    """``names`` in an order drawn at random (the system's CSPRNG), with one of ``repeat_of``
    (default: none) photographed a second time as ``repeat-<name>``, placed at random but never
    right after its first photo. Returns (the order, the repeat's name or None)."""
    rng = rng or secrets.SystemRandom()
    order = list(names)
    rng.shuffle(order)
    if not repeat_of:
        return order, None
    first = rng.choice(list(repeat_of))
    repeat = f"repeat-{first}"
    spots = [k for k in range(len(order) + 1) if k == 0 or order[k - 1] != first]
    order.insert(rng.choice(spots), repeat)
    return order, repeat


def rms_lab(a: NDArray, b: NDArray) -> NDArray[np.float64]:
    """(...) RMS over the last axis (the three CIELAB channels) of ``a - b``."""
    d = np.asarray(a, dtype=np.float64) - np.asarray(b, dtype=np.float64)
    return np.sqrt(np.mean(d * d, axis=-1))


def photo_noise(first: NDArray, second: NDArray) -> float:
    """Noise (rms Lab) of one photo from two photos of the same state, (N, 3) CIELAB each: the
    median over pixels of their difference's RMS over sqrt(2)."""
    return float(np.median(rms_lab(first, second)) / np.sqrt(2.0))


def model_noise(model: PixelColourModel, commanded_mm: NDArray) -> float:
    """Spread (rms Lab) of the model pixel's colour over the tuft layouts it averages, at the
    photographed ``commanded_mm`` (N, K); without layouts (one recorded) the photo floor
    :data:`~grassd.daemon.measure.pixel_model.PHOTO_LAB_SD`."""
    from grassd.daemon.measure.pixel_model import PHOTO_LAB_SD

    sd = getattr(model, "layout_sd", None)
    if sd is None:
        return PHOTO_LAB_SD
    cmd = np.asarray(commanded_mm, dtype=np.float64)
    per = np.stack([np.stack([np.interp(cmd[i], model.grid_mm, sd[i, :, c]) for c in range(3)],
                             axis=-1) for i in range(cmd.shape[0])])  # (N, K, 3)
    return float(max(np.median(np.sqrt(np.mean(per * per, axis=-1))), PHOTO_LAB_SD))


def at_bound(variation: DisplayVariation) -> NDArray[np.bool_]:
    """(N,) pixels whose fitted offset or a gain lies within :data:`BOUND_MARGIN` of its
    bound (:data:`~grassd.daemon.core.calibration.variation.OFFSET_LIMIT_MM`, ``GAIN_RANGE``)."""
    from grassd.daemon.core.calibration.variation import GAIN_RANGE, OFFSET_LIMIT_MM

    lo, hi = GAIN_RANGE
    off = np.abs(variation.length_offset_mm) >= OFFSET_LIMIT_MM * (1.0 - BOUND_MARGIN)
    gains = np.stack([variation.green_gain, variation.yellow_gain])
    gain = np.any((gains <= lo * (1.0 + BOUND_MARGIN)) | (gains >= hi * (1.0 - BOUND_MARGIN)),
                  axis=0)
    return off | gain


def name_mismatches(measured_lab: NDArray, predicted_lab: NDArray, limit_lab: float,
                    refit: Refit | None = None) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """The shots whose photos do not show their state: (each shot's median per-pixel RMS
    residual (K,), the shots named (K,) bool), ``measured_lab`` and ``predicted_lab`` (N, K, 3)
    CIELAB, ``limit_lab`` the most a shot's residual may be (rms Lab).

    With ``refit`` (a fit of the shots kept), while a kept shot is over the limit the worst is
    left out and the model fitted again without it, at most :data:`MOST_REFITS` times; the
    residuals are then against the last fit (a shot left out is judged by a fit it did not
    pull), and the shots named are those left out and any still over the limit. Without it,
    those over the limit against ``predicted_lab``."""
    measured = np.asarray(measured_lab, dtype=np.float64)
    per_shot = np.median(rms_lab(measured, predicted_lab), axis=0)
    kept = np.ones(per_shot.shape, dtype=bool)
    if refit is None:
        return per_shot, per_shot > limit_lab
    for _ in range(MOST_REFITS):
        over = kept & (per_shot > limit_lab)
        if not over.any() or kept.sum() <= 1:
            break
        kept[np.argmax(np.where(kept, per_shot, -np.inf))] = False
        per_shot = np.median(rms_lab(measured, refit(kept)), axis=0)
    return per_shot, ~kept | (per_shot > limit_lab)


def judge(names: Sequence[str], measured_lab: NDArray, predicted_lab: NDArray,
          fit_rms_lab: NDArray, variation: DisplayVariation, repeat: tuple[NDArray, NDArray],
          model_noise_lab: float, order: Sequence[str], refit: Refit | None = None) -> Evidence:
    """Judge the photos before the correction (module docstring). ``names`` (K,) the shots
    whose ``measured_lab`` (N, K, 3) and ``predicted_lab`` (N, K, 3; the fitted model at the
    lengths each commanded) are compared; ``fit_rms_lab`` (N,) the fit's per-pixel residuals;
    ``variation`` the fitted DisplayVariation; ``repeat`` the (N, 3) CIELAB of the repeated
    state's two photos; ``model_noise_lab`` :func:`model_noise`; ``order`` the shots as taken;
    ``refit`` the fit of a subset of the shots (:func:`name_mismatches`; None: the shots are
    judged by the one fit)."""
    photo = photo_noise(*repeat)
    noise = float(np.hypot(min(photo, MAX_PHOTO_NOISE_LAB), model_noise_lab))
    per_shot, named = name_mismatches(measured_lab, predicted_lab, SHOT_FACTOR * noise, refit)
    fit_rms = float(np.median(fit_rms_lab))
    bound = at_bound(variation)
    ev = Evidence(noise_lab=noise, photo_noise_lab=photo, model_noise_lab=model_noise_lab,
                  fit_rms_lab=fit_rms,
                  shot_rms_lab={n: float(v) for n, v in zip(names, per_shot, strict=True)},
                  at_bound=int(bound.sum()), order=tuple(order))
    if photo > MAX_PHOTO_NOISE_LAB:
        ev = ev.with_finding(Finding(
            Refusal.PHOTO_NOISE, f"two photos of the same display state differ by {photo:.2f} "
            f"rms Lab (over {MAX_PHOTO_NOISE_LAB:g}): the camera's photos are too noisy, or not "
            "of the display, to judge a correction by"))
    if fit_rms > RESIDUAL_FACTOR * noise:
        ev = ev.with_finding(Finding(
            Refusal.FIT_RESIDUAL, f"the fit's median residual is {fit_rms:.2f} rms Lab, over "
            f"{RESIDUAL_FACTOR:g} x the measurement's noise of {noise:.2f}: the photos do not "
            "show a display the model explains"))
    if bound.sum() > BOUND_FRACTION * len(bound):
        ev = ev.with_finding(Finding(
            Refusal.OFFSETS_AT_BOUND, f"{int(bound.sum())} of {len(bound)} pixels' fitted "
            f"offset or gain lies at its bound (over {BOUND_FRACTION:.0%}): implausible for a "
            "display; check the camera and the display's motors"))
    bad = [n for n, b in zip(names, named, strict=True) if b]
    if bad:
        ev = ev.with_finding(Finding(
            Refusal.SHOT_MISMATCH, f"photo(s) {', '.join(bad)} do not show the display state "
            f"shown for them (median residual over {SHOT_FACTOR:g} x the noise of {noise:.2f} "
            "rms Lab): old photos, shots out of order or another display state; check the "
            "measuring camera", tuple(bad)))
    return ev


def verify(ev: Evidence, names: Sequence[str], measured_lab: NDArray,
           predicted_lab: NDArray) -> Evidence:
    """``ev`` with the verification photos judged: ``names`` (L,) the shots after the
    correction, ``measured_lab`` and ``predicted_lab`` (N, L, 3) (module docstring)."""
    from dataclasses import replace

    per_shot = np.median(rms_lab(measured_lab, predicted_lab), axis=0)
    ev = replace(ev, shot_rms_lab={**ev.shot_rms_lab, **{
        n: float(v) for n, v in zip(names, per_shot, strict=True)}})
    bad = [n for n, v in zip(names, per_shot, strict=True) if v > SHOT_FACTOR * ev.noise_lab]
    if bad:
        ev = ev.with_finding(Finding(
            Refusal.VERIFICATION, f"verification photo(s) {', '.join(bad)} disagree with what "
            f"the correction predicts (median residual over {SHOT_FACTOR:g} x the noise of "
            f"{ev.noise_lab:.2f} rms Lab); check the measuring camera", tuple(bad)))
    return ev
