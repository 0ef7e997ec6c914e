"""What a characteristic costs before it runs, and the cap on it.

A characteristic refined to a target standard error needs paths in proportion to the inverse
square of the target (the error falls as 1/sqrt(paths)), traced at each of its lengths; green
blades that splay are traced at nearly every length (:data:`SPLAY_FACTOR`), and a sun's light
and shadow need larger replicates (:data:`SUN_FACTOR`). One unit is one length refined to
:data:`~grassd.daemon.studio.inputs.TARGET_STDERR` without sun or splay; the factors and the
cap's choice are in ``docs/studio.md``.
"""

from __future__ import annotations

import math

from grassd.daemon.studio.inputs import TARGET_STDERR, Condition, StudioInputError

#: A characteristic's cost with splayed blades, as a multiple of the same without.
SPLAY_FACTOR: float = 2.3
#: A characteristic's cost under a sun, as a multiple of the same in diffuse light.
SUN_FACTOR: float = 2.5


class JobTooCostly(StudioInputError):
    """A request whose estimated cost is above the studio's cap; the message says the cap and
    how to lower the request."""


def job_cost(cond: Condition, splay_deg: float) -> float:
    """The cost (units: one length to :data:`TARGET_STDERR` dE00, no sun, no splay) of
    refining ``cond``'s characteristic to its target, its blades splayed by ``splay_deg``
    (deg; the condition's, else its pixel's)."""
    factor = (SPLAY_FACTOR if splay_deg > 0 else 1.0) * (SUN_FACTOR if has_sun(cond) else 1.0)
    return len(cond.lengths_mm) * (TARGET_STDERR / cond.target_stderr) ** 2 * factor


def has_sun(cond: Condition) -> bool:
    """Whether ``cond`` lights the display with a sun (a measured sun counts, whether or not
    the light source has one: the estimate is made before the light is read)."""
    return cond.sun.mode != "none" and (cond.sun.mode == "measured" or cond.sun.lux > 0)


def check_cost(cond: Condition, splay_deg: float, cap: float, what: str = "this request") -> None:
    """Raise :class:`JobTooCostly` when ``cond``'s :func:`job_cost` is above ``cap`` (units),
    naming ``what`` and the largest target standard error, or the most lengths, that fit."""
    cost = job_cost(cond, splay_deg)
    if cost <= cap:
        return
    n = len(cond.lengths_mm)
    per_length = cost / n
    # the smallest target at these lengths, the most lengths at this target, that fit the cap
    target = cond.target_stderr * math.sqrt(cost / cap)
    fewer = int(cap // per_length)
    parts = [f"a target_stderr of at least {math.ceil(target * 1000) / 1000:g} dE00"]
    if fewer >= 2:
        parts.append(f"at most {fewer} lengths")
    raise JobTooCostly(
        f"{what} would cost about {cost:.0f} units ({n} lengths x "
        f"({TARGET_STDERR:g} / {cond.target_stderr:g} dE00)^2"
        + (f" x {SPLAY_FACTOR:g} for the splay" if splay_deg > 0 else "")
        + (f" x {SUN_FACTOR:g} for the sun" if has_sun(cond) else "")
        + f"); the studio runs at most {cap:.0f}: ask for " + " or ".join(parts))


__all__ = ["SPLAY_FACTOR", "SUN_FACTOR", "JobTooCostly", "check_cost", "has_sun", "job_cost"]
