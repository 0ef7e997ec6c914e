"""The studio's pace: a splayed characteristic takes replicates of fewer paths (its
every length is traced), one under a low sun goes on with larger replicates, and a run stops
between the renderer's launches when a newer input comes in, not only between rounds."""

from __future__ import annotations

import pytest
from conftest import LOW_SUN, studio_and_condition

from grassd.daemon.studio import pace
from grassd.daemon.studio.pace import studio_pace
from grassd.daemon.studio.worker import Superseded


def test_a_splayed_characteristic_takes_smaller_replicates_and_as_many_paths():
    assert studio_pace(0.0, 11) == (pace.STUDIO_SAMPLES, pace.ROUND_REPLICATES,
                                    pace.MAX_REPLICATES)
    assert studio_pace(6.0, 2) == studio_pace(0.0, 2)  # the audience map's two lengths
    samples, per_round, most = studio_pace(6.0, 11)
    assert samples == pace.SPLAY_SAMPLES < pace.STUDIO_SAMPLES
    assert samples * per_round == pace.STUDIO_SAMPLES * pace.ROUND_REPLICATES
    assert samples * most == pace.STUDIO_SAMPLES * pace.MAX_REPLICATES
    assert per_round <= 64  # a render's replicate limit (grassd.sim.scene.MAX_REPLICATES)


def test_a_low_sun_converges_on_larger_replicates(renderer, shared_hdri):
    """Under a low sun the first look (4 x 1024 paths) or the second (8 x 1024) says the target
    needs more than 64 x 1024, so the run goes on with replicates of 8192 paths: it meets
    0.1 dE00 with 8-32 of them (with replicates of 1024 it took 106-149, 2.4 s against 1.4 s).
    A round adds replicates to its series, so a round with no more than the last starts the new
    series."""
    from grassd.daemon.core.calibration.simulation import LargerReplicates

    st, cond = studio_and_condition(shared_hdri("courtyard"), {
        "ambient_lux": 5000, "viewpoint": [170, 2, 3],
        "sun": LOW_SUN})
    seen = []
    curve = st.characteristic(cond, target_stderr=0.1, on_round=seen.append)
    counts = [c.replicates for c in seen]
    assert counts[0] == pace.FIRST_REPLICATES
    assert next(i for i in range(1, len(counts)) if counts[i] <= counts[i - 1]) <= 2, counts
    assert LargerReplicates().least <= curve.replicates <= 32
    assert float(curve.ogcd_stderr.max()) <= 0.1 and seen[-1] is curve
    assert curve.paths_traced > 0 and curve.ogcd[-1] > 20  # the sunlit blades' contrast


def test_a_round_stops_between_launches(renderer, shared_hdri):
    st, cond = studio_and_condition(shared_hdri("courtyard"), {"ambient_lux": 5000,
                                                   "viewpoint": [170, 2, 7]})
    calls = []

    def check() -> None:
        calls.append(1)
        if len(calls) == 2:
            raise Superseded("a newer input")

    with pytest.raises(Superseded):  # 8 replicates of 1024 paths: 4 launches, stopped at 2
        st.characteristic(cond, target_stderr=None, replicates=8, check=check)
    assert len(calls) == 2


def test_every_round_is_armed_through_the_first_image(renderer, shared_hdri):
    """Where a newer input stops the launch in flight (the simulator process's interrupts),
    every round of the characteristic runs under the job's interrupt, also the rounds after
    the pixel's first image, which is drawn within the run (its own set-up must not replace the
    run's). Each round is one launch there, so its interrupt is armed once a round."""
    import numpy as np

    from grassd.sim.interrupt import Interrupt

    made: list = []

    class Counting(Interrupt):
        arms = 0

        def arm(self) -> int:
            self.arms += 1
            return super().arm()

    def interrupts(check):
        made.append(Counting(np.zeros(1, np.int32)))
        return made[-1]

    st, cond = studio_and_condition(shared_hdri("courtyard"), {"ambient_lux": 5000,
                                                   "viewpoint": [170, 2, 9]})
    st.interrupts = interrupts
    sent: list[dict] = []

    def check() -> None:  # ends the job once the characteristic converged
        if any(m["type"] == "curve" and m["converged"] for m in sent):
            raise Superseded("enough")

    with pytest.raises(Superseded):
        st.run(cond, sent.append, check)
    rounds = [m for m in sent if m["type"] == "curve"]
    assert len(rounds) >= 3 and any(m["type"] == "pixel" for m in sent)
    assert made[0].arms == len(rounds)  # the characteristic's; the image's came after it
    assert renderer.interrupt is None
