"""A characteristic that a newer input stops before it converged is kept, and the condition's
next job goes on from its last complete round, showing its curve so far before anything is
traced (a low sun's run stopped as it turned to larger replicates shows the last curve it had
shown); it converges to the curve of a run never stopped."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import LOW_SUN, studio_and_condition

from grassd.daemon.studio.worker import Superseded


def _stopped_then_resumed(hdri, condition: dict, stop_at: int):
    """(the curve of a run never stopped, the curves shown before the stop at on_round call
    ``stop_at``, the calls on resuming as ('curve', replicates) / ('launch',), the resumed
    run's curve, the studio)."""
    fresh, cond = studio_and_condition(hdri, condition)
    whole = fresh._converged(cond, lambda: None)

    st, cond = studio_and_condition(hdri, condition)
    seen: list = []

    def stop(curve) -> None:
        seen.append(curve)
        if len(seen) == stop_at:
            raise Superseded("a newer input")

    with pytest.raises(Superseded):
        st._converged(cond, lambda: None, stop)
    assert len(st._runs) == 1 and not st._curves

    calls: list = []
    curve = st._converged(cond, lambda: calls.append(("launch",)),
                          lambda c: calls.append(("curve", c.replicates)))
    return whole, seen, calls, curve, st


def _same(a, b) -> None:
    assert np.array_equal(a.ogcd, b.ogcd) and np.array_equal(a.ogcd_stderr, b.ogcd_stderr)
    assert a.replicates == b.replicates and a.rounds == b.rounds


def test_a_stopped_characteristic_goes_on_where_it_stopped(renderer, shared_hdri):
    whole, seen, calls, curve, st = _stopped_then_resumed(
        shared_hdri("courtyard"), {"ambient_lux": 5000, "viewpoint": [170, 2, 7],
                                   "target_stderr": 0.05}, stop_at=2)
    assert len(whole.rounds) > 2
    assert calls[0] == ("curve", seen[1].replicates)  # shown at once, nothing traced before
    _same(curve, whole)
    assert not st._runs and st._curves  # converged: kept as a curve, the run dropped


def test_a_low_sun_run_stopped_at_its_larger_replicates_shows_its_last_curve(renderer,
                                                                             shared_hdri):
    """The second round judges the paths needed and turns to replicates of 8192 paths; stopped
    there, the next job shows that round's curve at once (the new series has none to show
    yet), then goes on with the larger replicates as a run never stopped does."""
    whole, seen, calls, curve, _st = _stopped_then_resumed(
        shared_hdri("courtyard"), {"ambient_lux": 5000, "viewpoint": [170, 2, 3],
                                   "sun": LOW_SUN}, stop_at=2)
    assert calls[0] == ("curve", seen[1].replicates) and calls[1] == ("launch",)
    counts = [n for n, _worst in curve.rounds]  # the larger series counts from 0 again
    assert any(b < a for a, b in zip(counts, counts[1:], strict=False))
    _same(curve, whole)
