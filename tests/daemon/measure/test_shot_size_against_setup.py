"""A measurement shot is read only at the set-up shot's size: a DNG from the measuring camera
that declares 16384 x 8192 photosites (within the RAW limit, MAX_RAW_PIXELS, but not the
set-up's sensor) is refused from its header by the measurement's shot reading
(``develop_shot``), naming both sizes, in a process whose peak resident memory stays under
300 MiB (grassd measure peaked at 3168 MiB developing it). A shot of the set-up's size is
developed, to float32."""

from __future__ import annotations

import json
import struct
import subprocess
import sys
import textwrap

import numpy as np
import pytest
import tifffile

from grassd.calib.dng import DngCamera, mosaic, write_dng
from grassd.calib.raw import MAX_RAW_PIXELS, raw_sensor
from grassd.daemon.measure.camera_chain import Exposure, MeasureSetup

pytestmark = pytest.mark.timeout(120)

PEAK_MIB = 300.0

#: Runs develop_shot in a fresh process: prints the outcome and the peak RSS (VmHWM) as JSON.
CHILD = textwrap.dedent("""
    import json, sys
    from pathlib import Path
    from grassd.daemon.measure.camera_chain import (Exposure, MeasureSetup, Shot,
                                                    develop_shot)
    setup = MeasureSetup.from_json(json.loads(Path(sys.argv[1]).read_text()))
    out = {}
    try:
        img = develop_shot(Shot(Path(sys.argv[2]), Exposure(0.01, 100, 5.6)), setup, 2500.0)
        out.update(shape=list(img.shape), dtype=str(img.dtype))
    except Exception as exc:
        out.update(error=type(exc).__name__, message=str(exc))
    for line in open("/proc/self/status"):
        if line.startswith("VmHWM:"):
            out["peak_mib"] = int(line.split()[1]) / 1024
    print(json.dumps(out))
""")


def _dng(path, width=128, height=64):
    cam = DngCamera()
    write_dng(path, mosaic(np.full((height, width, 3), 0.3), cam), cam)
    return path


def _declare(src, dest, width: int, height: int) -> int:
    """Copy DNG ``src`` to ``dest`` with ImageWidth / ImageLength patched (the pixel data
    stays the small original); returns the file's size in bytes."""
    data = bytearray(src.read_bytes())
    with tifffile.TiffFile(src) as tif:
        tags = {t.code: t for t in tif.pages[0].tags.values()}
    for code, value in ((256, width), (257, height)):
        fmt = "<H" if tags[code].dtype == 3 else "<I"
        struct.pack_into(fmt, data, tags[code].offset + 8, value)
    dest.write_bytes(bytes(data))
    return len(data)


def _setup(tmp_path, photo, sensor) -> str:
    setup = MeasureSetup((1.0, 1.0, 1.0, 1.0), 1.0, Exposure(0.01, 100, 5.6), 2500.0,
                         ((1.0, 0, 0), (0, 1.0, 0), (0, 0, 1.0)), "spydercheckr-24", str(photo),
                         "2026-11-27T00:00:00+00:00", sensor=sensor)
    path = tmp_path / f"setup-{sensor}.json"
    path.write_text(json.dumps(setup.to_json()))
    assert MeasureSetup.from_json(json.loads(path.read_text())).sensor == sensor
    return str(path)


def _shot(setup_json: str, dng) -> dict:
    done = subprocess.run([sys.executable, "-c", CHILD, setup_json, str(dng)],
                          capture_output=True, text=True, timeout=90)
    assert done.returncode == 0, done.stderr[-2000:]
    return json.loads(done.stdout.strip().splitlines()[-1])


def test_a_shot_declaring_another_sensor_is_refused_from_its_header(tmp_path):
    photo = _dng(tmp_path / "setup.dng")
    sensor = raw_sensor(photo)
    assert sensor == (128, 64)
    size = _declare(photo, tmp_path / "huge.dng", 16384, 8192)
    assert 16384 * 8192 <= MAX_RAW_PIXELS  # the RAW limit alone lets it through
    for setup_json in (_setup(tmp_path, photo, sensor),  # the set-up keeps its sensor
                       _setup(tmp_path, photo, None)):  # an older one: its photo's header
        out = _shot(setup_json, tmp_path / "huge.dng")
        print(f"\nDNG ({size} B) declaring 16384 x 8192: {out}")
        assert out.get("error") == "RawSizeError", out
        assert "declares a sensor of 16384 x 8192 photosites, not the 128 x 64" in out["message"]
        assert "nothing was decoded" in out["message"]
        assert out["peak_mib"] < PEAK_MIB, out


def test_a_shot_of_the_setups_size_is_developed_to_float32(tmp_path):
    photo = _dng(tmp_path / "setup.dng")
    shot = _dng(tmp_path / "shot.dng")
    out = _shot(_setup(tmp_path, photo, raw_sensor(photo)), shot)
    assert "error" not in out, out
    assert out["shape"][2] == 3 and out["dtype"] == "float32", out
    assert out["peak_mib"] < PEAK_MIB, out
