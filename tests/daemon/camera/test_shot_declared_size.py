"""The bracket's JPEG shots are opened with their declared size checked before Pillow decodes a
pixel: a 1 kB JPEG whose header declares 60000 x 30000 (Pillow's own bomb check) or 10000 x
5000 (over grassd's panorama limit, under Pillow's) is a typed CameraDownloadError naming the
size, at once and in little memory."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from grassd.daemon.camera.bracket import Shot, file_exposure, load_codes
from grassd.daemon.core.errors import CameraDownloadError
from grassd.rigs.peak_memory import refusal_cost
from grassd.sim.hdri import MAX_TEXELS

pytestmark = pytest.mark.timeout(60)

MiB = 1 << 20


def _jpeg(width: int = 32, height: int = 16) -> bytes:
    buf = io.BytesIO()
    Image.fromarray(np.full((height, width, 3), 120, np.uint8)).save(buf, "JPEG", quality=90)
    return buf.getvalue()


def _declaring(path: Path, width: int, height: int) -> Path:
    """A small real JPEG whose SOF0 header is patched to declare ``width`` x ``height``."""
    data = bytearray(_jpeg())
    sof = data.index(b"\xff\xc0")
    data[sof + 5: sof + 9] = height.to_bytes(2, "big") + width.to_bytes(2, "big")
    path.write_bytes(bytes(data))
    return path


def _refused(fn) -> tuple[str, float, int]:
    """(message, seconds, peak RSS growth in bytes) of fn(), which must raise
    CameraDownloadError."""
    return refusal_cost(fn, CameraDownloadError)


def _shot(path: Path) -> Shot:
    return Shot(path, 0.01, 0.01, 100.0, 5.6, "exif")


@pytest.mark.parametrize(("width", "height", "says"), [
    (60000, 30000, "too many pixels"),  # Pillow's DecompressionBombError, now typed
    (10000, 5000, f"10000 x 5000 = 50000000 pixels, over the limit of {MAX_TEXELS}"),
])
def test_jpeg_declaring_a_huge_size_is_refused_before_decoding(tmp_path, width, height, says):
    path = _declaring(tmp_path / "shot00.jpg", width, height)
    assert path.stat().st_size < 4096
    for fn in (lambda: load_codes([_shot(path)]), lambda: file_exposure(path)):
        msg, seconds, rss = _refused(fn)
        assert says in msg and "shot00.jpg" in msg
        assert seconds < 3.0 and rss < 32 * MiB, (seconds, rss)
    print(f"\nJPEG declaring {width} x {height}: refused in {seconds * 1e3:.1f} ms, "
          f"RSS +{rss / MiB:.1f} MiB")


def test_ordinary_shot_still_decodes(tmp_path):
    path = tmp_path / "ok.jpg"
    path.write_bytes(_jpeg(64, 32))
    (codes,) = load_codes([_shot(path)])
    assert codes.shape == (32, 64, 3) and abs(int(codes.mean()) - 120) <= 2
    assert file_exposure(path) == {}  # no EXIF in this one


def test_not_an_image_is_typed(tmp_path):
    path = tmp_path / "x.jpg"
    path.write_bytes(b"<html>captive portal</html>")
    with pytest.raises(CameraDownloadError, match="not a readable image"):
        file_exposure(path)
