"""A display variation file (``--sim-display-variation``) is read exactly, and a bad one is
refused naming its key and line."""

from __future__ import annotations

import numpy as np
import pytest

from grassd.daemon.core.calibration.variation import (
    DisplayVariation,
    VariationFileError,
    load_variation,
)


def test_listed_pixels_vary_and_the_rest_are_the_model_pixel(tmp_path):
    f = tmp_path / "var.toml"
    f.write_text("[[pixel]]\nindex = 3\nlength_offset_mm = 0.8\ngreen_gain = 0.9\n"
                 "yellow_gain = 1.1\n\n[[pixel]]\nindex = 0\ngreen_gain = 1.2\n")
    v = load_variation(f, 8)
    assert v.length_offset_mm.tolist() == [0, 0, 0, 0.8, 0, 0, 0, 0]
    assert v.green_gain.tolist() == [1.2, 1, 1, 0.9, 1, 1, 1, 1]
    assert v.yellow_gain.tolist() == [1, 1, 1, 1.1, 1, 1, 1, 1]


def test_the_written_text_reads_back_the_same(tmp_path):
    rng = np.random.default_rng(1)
    v = DisplayVariation(rng.uniform(-1, 1, 6), rng.uniform(0.8, 1.2, 6),
                         rng.uniform(0.8, 1.2, 6))
    f = tmp_path / "v.toml"
    f.write_text(v.to_toml())
    back = load_variation(f, 6)
    for name in ("length_offset_mm", "green_gain", "yellow_gain"):
        assert np.array_equal(getattr(back, name), getattr(v, name))


@pytest.mark.parametrize("text, key, line", [
    ("[[pixel]]\nindex = 8\n", "pixel[0].index", 2),
    ("[[pixel]]\nindex = 1\ngreen_gain = 9.0\n", "pixel[0].green_gain", 3),
    ("[[pixel]]\nindex = 1\nlength_offset_mm = -7\n", "pixel[0].length_offset_mm", 3),
    ("[[pixel]]\nindex = 1\n[[pixel]]\nindex = 1\n", "pixel[1].index", 4),
    ("[[pixel]]\nindex = 1\ngain = 1.0\n", "pixel[0].gain", 3),
])
def test_a_bad_file_names_key_and_line(tmp_path, text, key, line):
    f = tmp_path / "bad.toml"
    f.write_text(text)
    with pytest.raises(VariationFileError) as info:
        load_variation(f, 8)
    assert info.value.key == key and info.value.line == line, str(info.value)


def test_unreadable_and_not_toml_are_typed_errors(tmp_path):
    with pytest.raises(VariationFileError, match="cannot read"):
        load_variation(tmp_path / "missing.toml", 4)
    f = tmp_path / "x.toml"
    f.write_text("[[pixel]\n")
    with pytest.raises(VariationFileError, match="not valid TOML"):
        load_variation(f, 4)
