"""A measurement shot is read only at the set-up shot's size: a DNG from the measuring camera
that declares 16384 x 8192 photosites (within the RAW limit, MAX_RAW_PIXELS, but not the
set-up's sensor) is refused from its header by the measurement's shot reading
(``develop_shot``), naming both sizes, in a process whose peak resident memory stays under
300 MiB (grassd measure peaked at 3168 MiB developing it). A shot of the set-up's size is
developed, to float32."""

from __future__ import annotations

import json

import pytest

from grassd.calib.raw import MAX_RAW_PIXELS, raw_sensor
from grassd.daemon.measure.camera_chain import Exposure, MeasureSetup
from grassd.rigs.hostile_decodes import dng_declaring, run_child, small_dng

pytestmark = pytest.mark.timeout(120)

PEAK_MIB = 300.0

#: develop_shot of the DNG argv[2] with the set-up argv[1], as a measurement reads a shot.
SHOT = """
from pathlib import Path
from grassd.daemon.measure.camera_chain import Exposure, MeasureSetup, Shot, develop_shot
setup = MeasureSetup.from_json(json.loads(Path(sys.argv[1]).read_text()))
img = develop_shot(Shot(Path(sys.argv[2]), Exposure(0.01, 100, 5.6)), setup, 2500.0)
out.update(shape=list(img.shape), dtype=str(img.dtype))
"""


def _setup(tmp_path, photo, sensor) -> str:
    setup = MeasureSetup((1.0, 1.0, 1.0, 1.0), 1.0, Exposure(0.01, 100, 5.6), 2500.0,
                         ((1.0, 0, 0), (0, 1.0, 0), (0, 0, 1.0)), "spydercheckr-24", str(photo),
                         "2026-11-27T00:00:00+00:00", sensor=sensor)
    path = tmp_path / f"setup-{sensor}.json"
    path.write_text(json.dumps(setup.to_json()))
    assert MeasureSetup.from_json(json.loads(path.read_text())).sensor == sensor
    return str(path)


def test_a_shot_declaring_another_sensor_is_refused_from_its_header(tmp_path):
    photo = small_dng(tmp_path / "setup.dng")
    sensor = raw_sensor(photo)
    assert sensor == (128, 64)
    size = dng_declaring(photo, tmp_path / "huge.dng", 16384, 8192)
    assert 16384 * 8192 <= MAX_RAW_PIXELS  # the RAW limit alone lets it through
    for setup_json in (_setup(tmp_path, photo, sensor),  # the set-up keeps its sensor
                       _setup(tmp_path, photo, None)):  # an older one: its photo's header
        out = run_child(SHOT, setup_json, str(tmp_path / "huge.dng"))
        print(f"\nDNG ({size} B) declaring 16384 x 8192: {out}")
        assert out.get("error") == "RawSizeError", out
        assert "declares a sensor of 16384 x 8192 photosites, not the 128 x 64" in out["message"]
        assert "nothing was decoded" in out["message"]
        assert out["peak_mib"] < PEAK_MIB, out


def test_a_shot_of_the_setups_size_is_developed_to_float32(tmp_path):
    photo = small_dng(tmp_path / "setup.dng")
    shot = small_dng(tmp_path / "shot.dng")
    out = run_child(SHOT, _setup(tmp_path, photo, raw_sensor(photo)), str(shot))
    assert "error" not in out, out
    assert out["shape"][2] == 3 and out["dtype"] == "float32", out
    assert out["peak_mib"] < PEAK_MIB, out
