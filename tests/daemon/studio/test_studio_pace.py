"""The studio's pace (issue #29): a splayed characteristic takes replicates of fewer paths (its
every length is traced), and a run stops between the renderer's launches when a newer input
comes in, not only between rounds."""

from __future__ import annotations

import pytest

from grassd.daemon.studio import session
from grassd.daemon.studio.session import studio_pace
from grassd.daemon.studio.worker import Superseded


def test_a_splayed_characteristic_takes_smaller_replicates_and_as_many_paths():
    assert studio_pace(0.0, 11) == (session.STUDIO_SAMPLES, session.ROUND_REPLICATES,
                                    session.MAX_REPLICATES)
    assert studio_pace(6.0, 2) == studio_pace(0.0, 2)  # the audience map's two lengths
    samples, per_round, most = studio_pace(6.0, 11)
    assert samples == session.SPLAY_SAMPLES < session.STUDIO_SAMPLES
    assert samples * per_round == session.STUDIO_SAMPLES * session.ROUND_REPLICATES
    assert samples * most == session.STUDIO_SAMPLES * session.MAX_REPLICATES
    assert per_round <= 64  # a render's replicate limit (grassd.sim.scene.MAX_REPLICATES)


def test_a_round_stops_between_launches(renderer, shared_hdri):
    from grassd.daemon.config.settings import resolve_config
    from grassd.daemon.studio.inputs import parse_condition
    from grassd.daemon.studio.lights import Lights, LightSource

    st = session.Studio(resolve_config(None, None),
                        Lights([LightSource("file", "f", shared_hdri("courtyard"))]))
    cond = parse_condition({"ambient_lux": 5000, "viewpoint": [170, 2, 7]},
                           green_max_mm=st.display.pixel.green_max_mm,
                           timezone=st.cfg.site.timezone, lights=st.lights.names,
                           default_light=st.lights.default)
    calls = []

    def check() -> None:
        calls.append(1)
        if len(calls) == 2:
            raise Superseded("a newer input")

    with pytest.raises(Superseded):  # 8 replicates of 1024 paths: 4 launches, stopped at 2
        st.characteristic(cond, target_stderr=None, replicates=8, check=check)
    assert len(calls) == 2
