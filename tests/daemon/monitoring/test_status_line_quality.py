"""`grassd status` shows each serial line's quality: a noisy bus (1 % byte errors on its pty)
is reported as noisy, with the share of unanswered request tries and the TABLE_CHUNK size the
host cut its chunks to; a clean bus as good. In the JSON under ``lines``, and in the text."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from daemon_harness import POLICY, after_first_bundle

from grassd.daemon.cli.run import print_status
from grassd.daemon.core.monitoring.line_report import describe_line, line_verdict
from grassd.rigs.faults import FaultInjector, FaultPlan


def test_status_reports_a_noisy_line_and_a_good_one(tmp_path, hw):
    sim, cfg = hw
    # replies wait 1 s (not the harness's 0.1 s): on a loaded machine a clean line's late
    # answer must not count as unanswered; the noisy line's corrupt frames still do
    svc, _ = after_first_bundle(tmp_path, cfg, policy=replace(POLICY, timeout_s=1.0))
    noisy, clean = sim.buses[0], sim.buses[1]
    noisy.faults = FaultInjector(FaultPlan(flip=0.004, drop=0.003, duplicate=0.003), seed=7)
    # the daemon pushes a new table over both buses: on the noisy one a third of the tries
    # fail and the chunks shrink to 16 bytes, far past the thresholds asserted below (three
    # pushes took 46 s here for the same verdicts)
    new_table = np.random.default_rng(0).integers(0, 20001, 256).astype(np.uint16)
    svc.fleet.push(new_table, table_id=1000)
    st = svc.status()
    lines = st.daemon.lines
    assert set(lines) == {c.port for c in svc.fleet.controllers}
    bad = next(p for p in lines if p.endswith(noisy.link_path.name))
    good = next(p for p in lines if p.endswith(clean.link_path.name))
    assert line_verdict(lines[bad]) in ("noisy", "failing"), lines[bad]
    assert lines[bad]["recent_failure_rate"] > 0.05
    assert lines[bad]["smallest_chunk_bytes"] < lines[bad]["max_chunk_bytes"]
    assert line_verdict(lines[good]) == "good", lines[good]
    assert lines[good]["recent_failure_rate"] == 0.0
    out: list[str] = []
    print_status(st, echo=out.append)
    text = "\n".join(out)
    assert "serial lines:" in text
    assert describe_line(bad, lines[bad]) in text and "check the cable" in text
    assert f"{good}: good, 0.0% of the last" in text
