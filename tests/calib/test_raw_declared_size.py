"""grassd.calib.raw refuses a RAW file from its size on disk and the dimensions LibRaw reads from
its header, before any pixel is unpacked or developed: a 1.5 kB DNG declaring 30000 x 20000
photosites is refused at once, in little memory."""

from __future__ import annotations

import os
import struct

import numpy as np
import pytest
import tifffile

from grassd.calib import raw as raw_mod
from grassd.calib.dng import DngCamera, mosaic, write_dng
from grassd.calib.errors import RawReadError
from grassd.calib.raw import MAX_RAW_PIXELS, develop_raw, open_raw
from grassd.calib.raw_bracket import develop_bracket, saturated_texels
from grassd.rigs.peak_memory import refusal_cost

pytestmark = pytest.mark.timeout(60)

MiB = 1 << 20


def _refused(fn, path) -> tuple[str, float, int]:
    """(message, seconds, peak RSS growth in bytes) of fn(path), which must raise
    RawReadError."""
    return refusal_cost(lambda: fn(path), RawReadError)


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


def test_declared_sensor_beyond_the_limit_is_refused_before_decoding(tmp_path):
    good = _dng(tmp_path / "good.dng")
    size = _declare(good, tmp_path / "huge.dng", 30000, 20000)  # 600 Mpx
    assert size < 64 * 1024
    with open_raw(good) as raw:  # the untouched file passes
        assert (raw.sizes.raw_width, raw.sizes.raw_height) == (128, 64)
    for fn in (develop_raw, open_raw, saturated_texels, lambda p: develop_bracket([p])):
        msg, seconds, rss = _refused(fn, tmp_path / "huge.dng")
        assert "declares a sensor of 30000 x 20000 = 600000000 pixels" in msg
        assert str(MAX_RAW_PIXELS) in msg and "nothing was decoded" in msg
        assert seconds < 3.0 and rss < 64 * MiB, (seconds, rss)
    print(f"\nDNG ({size} B) declaring 30000 x 20000: refused in {seconds * 1e3:.1f} ms, "
          f"RSS +{rss / MiB:.1f} MiB")


def test_file_larger_than_the_limit_is_refused_before_libraw_opens_it(tmp_path, monkeypatch):
    good = _dng(tmp_path / "good.dng")
    monkeypatch.setattr(raw_mod, "MAX_RAW_FILE_BYTES", good.stat().st_size - 1)
    opened = []
    monkeypatch.setattr(raw_mod.rawpy, "imread", lambda p: opened.append(p))
    msg, _, _ = _refused(develop_raw, good)
    assert f"is {good.stat().st_size} bytes, more than the limit" in msg
    assert opened == []


def test_a_fifo_is_refused_without_opening_it(tmp_path):
    fifo = tmp_path / "shot.dng"
    os.mkfifo(fifo)
    msg, seconds, _ = _refused(develop_raw, fifo)
    assert "not a regular file" in msg and seconds < 3.0
