"""``grassd measure --now --simulate-hardware --sim-display-variation FILE``, end to end on the
embedded default config's 4 x 8 display: the pixels' hidden differences (a secret file grassd
never reads) are recovered from the camera's photos, and the per-pixel tables it pushes make the
display at least 3x more uniform (worst pixel pair, dE00, at mid level)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from grassd.daemon.core.calibration.variation import load_variation
from grassd.daemon.core.store.history import History
from grassd.daemon.core.store.layout import StateLayout

pytestmark = pytest.mark.long

GRASSD = str(Path(sys.executable).parent / "grassd")
SECRET = Path(__file__).resolve().parents[2] / "data" / "measure" / "secret_variation.toml"
FIELDS = ("length_offset_mm", "green_gain", "yellow_gain")


def test_measure_recovers_the_hidden_variation_and_makes_the_display_uniform(tmp_path):
    out = tmp_path / "out.json"
    run = subprocess.run(
        [GRASSD, "measure", "--now", "--state-dir",
         str(tmp_path / "state"), "--simulate-hardware", "--sim-display-variation", str(SECRET),
         "--json", str(out)], capture_output=True, text=True, timeout=900)
    assert run.returncode == 0, run.stderr[-3000:]
    report = json.loads(out.read_text())
    truth = load_variation(SECRET, 32)
    got = {f: np.array([p[f] for p in sorted(report["pixels"], key=lambda p: p["index"])])
           for f in FIELDS}
    r = {f: float(np.corrcoef(got[f], getattr(truth, f))[0, 1]) for f in FIELDS}
    print(f"correlation with the truth: {r}")  # -s shows the figures
    assert all(v >= 0.9 for v in r.values()), r
    u = report["uniformity"]
    print(f"worst pixel pair at level {u['level']}: {u['before']:.2f} -> {u['after']:.2f} dE00")
    assert u["after"] * 3.0 <= u["before"], u
    # the correction is kept, and its tables were pushed as a run of their own
    layout = StateLayout(tmp_path / "state")
    # the set-up's checker photo had no clipped patch (the simulated sensor's response is
    # never negative): its 3x3 correction predicts each patch left out of the fit (the
    # leave-one-out figures the set-up keeps; 0.58 / 5.22 with a sensor cutting at 0)
    mean_de, max_de = json.loads(layout.measure_setup.read_text())["ccm_de00"]
    print(f"checker colour correction: mean {mean_de:.2f}, max {max_de:.2f} dE00")
    assert mean_de < 0.3 and max_de < 1.0
    assert json.loads(layout.correction.read_text())["measurement"] == report["measurement"]
    run_id = report["tables"]["run_id"]
    assert report["tables"]["status"] == "ok" and all(report["tables"]["pushed"])
    history = History(layout.db)
    assert [x.trigger for x in history.runs(5) if x.id == run_id] == ["measure"]
    saved = json.loads(Path(report["report"]).read_text())
    assert saved["verdict"]["state"] in ("within tolerance", "recalibrate")
    assert Path(report["report"]).with_suffix(".html").exists()
    run_report = json.loads((layout.reports / f"run-{run_id:06d}.json").read_text())
    assert run_report["display_correction"] == report["measurement"]
