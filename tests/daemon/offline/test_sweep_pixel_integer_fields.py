"""``grassd sweep --pixel``: PixelSpec's int fields (layout_seed, slit_count) are parsed as ints;
a fraction, a negative or a non-number is a usage error naming the field, not a traceback."""

from __future__ import annotations

import numpy as np
import pytest
from click.testing import CliRunner

from grassd.daemon.offline.sweep import SweepError, parse_pixel_option


@pytest.fixture(scope="module")
def sky(tmp_path_factory):
    """A small real EXR panorama."""
    from grassd.sim.hdri import write_exr

    path = tmp_path_factory.mktemp("hdri") / "sky.exr"
    write_exr(path, np.ones((16, 32, 3), np.float32))
    return str(path)


def _sweep(sky, out, *pixels):
    from grassd.daemon.cli.main import main

    args = ["sweep", "--hdri", sky, "--view", "170,2,0", "--lengths", "0:20:10", "--samples",
            "64", "--replicates", "2", "--workers", "1", "--out", str(out)]
    for p in pixels:
        args += ["--pixel", p]
    return CliRunner().invoke(main, args)


def test_int_fields_parse_as_int_and_float_fields_as_float():
    assert parse_pixel_option("l1:layout_seed=1,slit_count=2.0,splay_deg=5") == (
        "l1", (("layout_seed", 1), ("slit_count", 2), ("splay_deg", 5.0)))
    name, fields = parse_pixel_option("big:layout_seed=123456789012345678901")
    assert fields == (("layout_seed", 123456789012345678901),)  # exact, not through a float
    assert all(type(v) is int for _, v in parse_pixel_option("a:layout_seed=1e3")[1])


@pytest.mark.parametrize("bad, words", [
    ("l:layout_seed=1.5", ["layout_seed", "whole number", "'1.5'"]),
    ("l:layout_seed=-1", ["layout_seed", ">= 0"]),
    ("l:slit_count=nan", ["slit_count", "not a number"]),
    ("l:splay_deg=inf", ["splay_deg", "not a number"]),
    ("l:yellow_srgb=1", ["FIELD=NUMBER", "layout_seed"]),  # a triple, not a number field
])
def test_bad_values_name_the_field(bad, words):
    with pytest.raises(SweepError) as exc:
        parse_pixel_option(bad)
    for w in words:
        assert w in str(exc.value)


def test_cli_layout_seed_fraction_is_a_usage_error(sky, tmp_path):
    res = _sweep(sky, tmp_path / "o", "l1:layout_seed=1.5")
    assert res.exit_code == 2, res.output
    assert "Invalid value for '--pixel'" in res.output
    assert "layout_seed must be a whole number" in res.output
    assert "Traceback" not in res.output
    assert res.exception is None or isinstance(res.exception, SystemExit)
    assert not (tmp_path / "o" / "sweep.sqlite").exists()  # refused before any work


def test_cli_layout_seed_int_runs(sky, tmp_path):
    res = _sweep(sky, tmp_path / "o", "l1:layout_seed=1", "l2:layout_seed=2")
    assert res.exit_code == 0, res.output
    assert "2 tasks: 0 already stored, 2 computed" in res.output
