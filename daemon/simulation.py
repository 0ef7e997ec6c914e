"""Simulated grass colour characteristics: the renderer (``sim``) composed with ``calib``.

``sim`` returns linear Rec.709 radiance (nits) with its Monte Carlo replicates; this module turns
it into CIELAB and OGCD the way a camera developed with a fixed white balance would see it:

1. White reference: the radiance of a perfect diffuse white lying flat at the display,
   ``W = E_h / pi`` per channel, where ``E_h`` is the horizontal irradiance of the lighting
   (environment plus sun). It is exact for an unoccluded card, so no render is needed.
2. Normalisation and white balance: every replicate is divided by ``W`` channel by channel
   (a von Kries white balance in linear Rec.709), so the white card reads (1, 1, 1), i.e. Y = 1
   at the D65 white, which the Bradford transform maps onto the D50 (ProPhoto/CIELAB) white.
   An 18 % grey card then reads Y = 0.18, the paper's exposure rule.
3. Optional colour-correction matrix (ProPhoto linear), then Lab and OGCD with
   correlation-aware standard errors from the replicates
   (:func:`grassd.calib.ogcd.ogcd_from_samples`; the replicates share random numbers across
   lengths, so their covariance is what makes the OGCD error small).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from grassd.calib.ogcd import ogcd_from_samples


@dataclass(frozen=True)
class SimulatedCurve:
    """One viewpoint's simulated characteristic.

    ``rgb_linear``/``rgb_stderr`` (n, 3): radiance in the scaled HDRI's units (nits), no
    normalisation; ``lab`` (n, 3) D50 CIELAB after normalisation (and CCM if given); ``ogcd``
    and ``ogcd_stderr`` (n,) in CIEDE2000 units. ``rounds``: (replicates so far, largest OGCD
    stderr then) after each batch of an adaptive run, one entry otherwise.
    """

    h_cm: float
    d_m: float
    theta_deg: float
    lengths_mm: np.ndarray
    rgb_linear: np.ndarray
    rgb_stderr: np.ndarray
    lab: np.ndarray
    ogcd: np.ndarray
    ogcd_stderr: np.ndarray
    replicates: int = 0
    seconds: dict[str, float] = field(default_factory=dict)
    rounds: tuple[tuple[int, float], ...] = ()

    def to_json(self) -> dict:
        """The per-viewpoint JSON object of ``grassd simulate --json``."""
        return {
            "h_cm": self.h_cm, "d_m": self.d_m, "theta_deg": self.theta_deg,
            "lengths_mm": self.lengths_mm.tolist(), "rgb_linear": self.rgb_linear.tolist(),
            "rgb_stderr": self.rgb_stderr.tolist(), "lab": self.lab.tolist(),
            "ogcd": self.ogcd.tolist(), "ogcd_stderr": self.ogcd_stderr.tolist(),
            "replicates": self.replicates,
        }


def white_radiance(lighting) -> np.ndarray:
    """Linear Rec.709 radiance (nits) of a perfect diffuse white lying flat at the display."""
    return np.asarray(lighting.horizontal_irradiance_rgb, dtype=np.float64) / math.pi


def simulate_curve(renderer, display, lighting, viewpoint, lengths_mm: np.ndarray, settings,
                   *, ccm=None, pixel_index: int = 0, target_stderr: float | None = None,
                   max_replicates: int = 256,
                   progress: Callable[[int, int], None] | None = None) -> SimulatedCurve:
    """Render one viewpoint at ``lengths_mm`` (mm, first = reference) and derive its OGCD.

    With ``target_stderr`` (CIEDE2000), further batches of ``settings.replicates`` independent
    replicates (new seeds, same random numbers across lengths within a replicate) are traced
    until the largest OGCD standard error is at most the target or ``max_replicates`` is
    reached; each batch is sized from the 1/sqrt(R) law, at most doubling the count, and may be
    a single replicate (the first round's estimate often lands just above the target: a
    replicate of 4096 paths x 21 lengths costs about 0.1 s on 2 cores).
    """
    lengths_mm = np.asarray(lengths_mm, float)
    white = white_radiance(lighting)
    reps: list[np.ndarray] = []
    seconds = {"compile": 0.0, "trace": 0.0, "colour": 0.0}
    batch = settings.replicates
    k = 0
    rounds: list[tuple[int, float]] = []
    while True:
        s = replace(settings, replicates=batch, seed=(settings.seed + 7919 * k) % 2**31)
        m = renderer.characteristic(display, lighting, viewpoint, lengths_mm, s,
                                    pixel_index=pixel_index, progress=progress)
        seconds["compile"] += m.seconds.get("compile", 0.0)
        seconds["trace"] += m.seconds.get("trace", 0.0)
        reps.append(m.rgb_replicates)
        t0 = time.perf_counter()
        all_reps = np.concatenate(reps)
        res = ogcd_from_samples(np.clip(all_reps / white, 0.0, None), space="rec709", ccm=ccm)
        seconds["colour"] += time.perf_counter() - t0
        n = len(all_reps)
        worst = float(np.max(res.ogcd_stderr))
        rounds.append((n, worst))
        if target_stderr is None or worst <= target_stderr or n >= max_replicates:
            break
        # The worst of n noisy error estimates overstates the error: grow at most 2x a round.
        needed = int(math.ceil(n * min((worst / target_stderr) ** 2, 2.0))) - n
        batch = int(min(max(needed, 1), max_replicates - n))
        k += 1
    return SimulatedCurve(
        h_cm=viewpoint.h_cm, d_m=viewpoint.d_m, theta_deg=viewpoint.theta_deg,
        lengths_mm=lengths_mm, rgb_linear=all_reps.mean(axis=0),
        rgb_stderr=all_reps.std(axis=0, ddof=1) / math.sqrt(n), lab=res.lab, ogcd=res.ogcd,
        ogcd_stderr=res.ogcd_stderr, replicates=n, seconds=seconds, rounds=tuple(rounds),
    )


def simulate_curves(renderer, display, lighting, viewpoints: Sequence, lengths_mm: np.ndarray,
                    settings, *, ccm=None, pixel_index: int = 0,
                    target_stderr: float | None = None,
                    progress: Callable[[int], None] | None = None
                    ) -> tuple[list[SimulatedCurve], dict[str, float]]:
    """:func:`simulate_curve` for every viewpoint; returns the curves and summed seconds
    (``compile``, ``trace``, ``colour``, ``total``). ``progress(k)`` is called with the number of
    lengths finished since the last call."""
    t0 = time.perf_counter()
    curves = []
    for vp in viewpoints:
        done = [0]

        def step(k: int, _n: int, done=done) -> None:
            if progress and k > done[0]:  # later adaptive batches restart at 0: not counted
                progress(k - done[0])
                done[0] = k

        curves.append(simulate_curve(renderer, display, lighting, vp, lengths_mm, settings,
                                     ccm=ccm, pixel_index=pixel_index,
                                     target_stderr=target_stderr, progress=step))
    seconds = {k: float(sum(c.seconds.get(k, 0.0) for c in curves))
               for k in ("compile", "trace", "colour")}
    seconds["total"] = time.perf_counter() - t0
    return curves, seconds
