"""An adaptive run that an exception stops (a newer input in the studio) goes on from its last
complete round when called again with its :class:`CurveRun`: the same rounds and seeds as a run
never stopped, so the same curve; a round stopped part-way is traced again whole."""

from __future__ import annotations

import numpy as np
import pytest

from grassd.daemon.core.calibration.simulation import CurveRun, simulate_curve
from grassd.sim.errors import SceneError
from grassd.sim.light_input import LightInput
from grassd.sim.scene import DisplaySpec, RenderSettings, Viewpoint

LENGTHS = np.arange(0.0, 20.01, 2.5)
# (the seed and target of the adaptive test in tests/sim/test_sim_render.py: several rounds)
SETTINGS = RenderSettings(samples=256, replicates=4, seed=4)


class Stop(Exception):
    """What the caller raises to stop the run."""


@pytest.fixture(scope="module")
def lighting(shared_hdri):
    return LightInput(shared_hdri("courtyard"), 8000.0).lighting()


@pytest.fixture(scope="module")
def target_and_whole(renderer, lighting):
    """A target that takes several rounds (0.6 of a first round's largest error) and the run
    to it never stopped."""
    plain = _run(renderer, lighting, None)
    target = 0.6 * float(plain.ogcd_stderr.max())
    return target, _run(renderer, lighting, target)


def _run(renderer, lighting, target, **kw):
    return simulate_curve(renderer, DisplaySpec(), lighting, Viewpoint(), LENGTHS, SETTINGS,
                          target_stderr=target, **kw)


def _same(a, b) -> None:
    assert np.array_equal(a.ogcd, b.ogcd) and np.array_equal(a.ogcd_stderr, b.ogcd_stderr)
    assert a.rounds == b.rounds and a.paths_traced == b.paths_traced
    assert np.array_equal(a.length_replicates, b.length_replicates)


def test_a_run_stopped_after_a_round_goes_on_from_it(renderer, lighting, target_and_whole):
    target, whole = target_and_whole
    assert len(whole.rounds) >= 3

    run, seen = CurveRun(), []

    def stop_at_second(curve) -> None:
        seen.append(curve)
        if len(seen) == 2:
            raise Stop

    with pytest.raises(Stop):
        _run(renderer, lighting, target, on_round=stop_at_second, resume=run)
    assert run.k == 2 and len(run.blocks) == 2  # its two rounds, the third decided

    again = []
    curve = _run(renderer, lighting, target, on_round=again.append, resume=run)
    _same(curve, whole)
    # the stopped run's last curve is shown first, before anything more is traced
    assert again[0].replicates == seen[1].replicates
    assert np.array_equal(again[0].ogcd, seen[1].ogcd) and again[0].rounds == seen[1].rounds
    assert again[-1] is curve and len(again) == len(whole.rounds) - 1


def test_a_round_stopped_part_way_is_traced_again_whole(renderer, lighting,
                                                      target_and_whole):
    target, whole = target_and_whole
    run, calls = CurveRun(), []

    def progress(done: int, total: int) -> None:  # the renderer's, during a round's launch
        calls.append(done)
        if len(calls) == 3:
            raise Stop

    with pytest.raises(Stop):
        _run(renderer, lighting, target, progress=progress, resume=run)
    kept = (run.k, len(run.blocks), run.counts.copy())
    assert run.k >= 1  # a round or more completed before the stop
    curve = _run(renderer, lighting, target, resume=run)
    _same(curve, whole)
    assert kept[1] == kept[0] and np.all(kept[2] <= whole.length_replicates)


def test_a_run_goes_on_only_as_it_was_asked(renderer, lighting):
    run = CurveRun()

    def stop(_curve) -> None:
        raise Stop

    with pytest.raises(Stop):
        _run(renderer, lighting, 0.01, on_round=stop, resume=run)
    with pytest.raises(SceneError, match="goes on only with the lengths"):
        simulate_curve(renderer, DisplaySpec(), lighting, Viewpoint(), LENGTHS[:3], SETTINGS,
                       target_stderr=0.01, resume=run)
    with pytest.raises(SceneError, match="goes on only with the lengths"):
        _run(renderer, lighting, 0.02, resume=run)  # another target


def test_a_run_stopped_before_it_decided_its_next_round_decides_it_on_going_on(
        renderer, lighting, target_and_whole, monkeypatch):
    """An exception between a traced round and the next round's decision (here in deciding
    it): going on, the run takes that round as traced, decides once, and ends as a run never
    stopped."""
    from grassd.daemon.core.calibration import simulation

    target, whole = target_and_whole
    decide = simulation._next_round
    calls = []

    def fails_once(*args, **kw):
        calls.append(1)
        if len(calls) == 2:
            raise Stop
        return decide(*args, **kw)

    run = CurveRun()
    monkeypatch.setattr(simulation, "_next_round", fails_once)
    with pytest.raises(Stop):
        _run(renderer, lighting, target, resume=run)
    assert not run.decided and len(run.rounds) == len(run.blocks) - 1
    _same(_run(renderer, lighting, target, resume=run), whole)
