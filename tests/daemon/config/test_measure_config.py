"""The ``[measure]`` section: the measuring camera, its schedule window and limits, each bad
value refused naming key and line."""

from __future__ import annotations

from importlib import resources

import pytest

from grassd.daemon.core.config.settings import load_config
from grassd.daemon.core.errors import ConfigError
from grassd.daemon.measure.config import MeasureConfig

DEFAULT = resources.files("grassd.daemon.core.config").joinpath("default.toml").read_text()


def _load(tmp_path, measure: str):
    path = tmp_path / "grassd.toml"
    path.write_text(DEFAULT + "\n[measure]\n" + measure)
    return load_config(path)


def test_a_second_camera_with_defaults(tmp_path):
    m = _load(tmp_path, 'camera = "http://192.168.1.2"\ninterval_s = 604800\n').measure
    assert m.camera == "http://192.168.1.2" and m.interval_s == 604800
    assert m.patterns == MeasureConfig.patterns and m.tolerance_de00 == MeasureConfig.tolerance_de00


@pytest.mark.parametrize("text, key, words", [
    ('camera = "capture"\n', "measure.camera", "no [capture] section"),
    ('camera = "ftp://x"\n', "measure.camera", "http:// URL"),
    ('camera = "http://x"\ninterval_s = 60\n', "measure.interval_s", "0 (only on request)"),
    ('camera = "http://x"\npatterns = 2\n', "measure.patterns", "between"),
    ('camera = "http://x"\nwatchdog = 5\n', "measure.watchdog", "unknown key"),
    ('camera = "http://x"\ndeadline_s = 5\n', "measure.deadline_s", "between 10.0 and"),
    ('camera = "http://x"\nkeep_photos = 0\n', "measure.keep_photos", "between 1 and"),
])
def test_bad_values_name_key_and_line(tmp_path, text, key, words):
    with pytest.raises(ConfigError) as info:
        _load(tmp_path, text)
    assert info.value.key == key and words in str(info.value), str(info.value)
    assert info.value.line is not None and info.value.line > DEFAULT.count("\n")


def test_the_window_may_span_midnight():
    day, night = MeasureConfig(start_hour=10, end_hour=14), MeasureConfig(start_hour=22,
                                                                          end_hour=4)
    assert [h for h in range(24) if day.in_window(h)] == [10, 11, 12, 13]
    assert [h for h in range(24) if night.in_window(h)] == [0, 1, 2, 3, 22, 23]
