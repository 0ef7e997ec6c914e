"""The interim ``grassd demo`` command (the calib doctests run in ``tests/test_doctests.py``)."""

from __future__ import annotations

import re

from click.testing import CliRunner

from grassd.daemon.cli.demo import example_pixel_rgb, green_coverage
from grassd.daemon.cli.main import main


def test_example_model_is_an_s_curve_between_two_albedos():
    import numpy as np

    x = np.linspace(0, 20, 41)
    c = green_coverage(x)
    assert np.all(np.diff(c) > 0) and c[0] < 0.01 and 0.45 < c[-1] < 0.52
    rgb = example_pixel_rgb(x)
    assert np.all(np.diff(rgb[:, 1] / rgb[:, 0]) > 0)  # greener as it grows


def test_grassd_demo_prints_table_summary():
    result = CliRunner().invoke(main, ["demo", "--example-curve"])
    assert result.exit_code == 0, result.output
    out = result.output
    m = re.search(r"R\^2 before ([0-9.]+) -> after ([0-9.]+)", out)
    assert m, out
    before, after = float(m.group(1)), float(m.group(2))
    assert before < 0.95 and after >= 0.999
    assert re.search(r"OGCD range [0-9.]+ dE00", out)
    assert "0: 0," in out and "255: 20000" in out


def test_grassd_demo_with_noise_and_full_table():
    result = CliRunner().invoke(
        main, ["demo", "--example-curve", "--noise", "0.02", "--full", "--lengths", "41"]
    )
    assert result.exit_code == 0, result.output
    entries = re.findall(r"(\d+): (\d+)", result.output.split("level -> length (um):")[1])
    assert len(entries) == 256
    lengths = [int(v) for _, v in entries]
    assert lengths == sorted(lengths) and lengths[0] == 0
