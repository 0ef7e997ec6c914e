"""The studio's picture decoder refuses by the header before it allocates: a 268 KiB PNG of
8192 x 8192 (a flat image, so nothing but its size is wrong) is refused with its size and
the limit, in a process whose peak resident memory stays under 300 MiB (four such uploads
took the studio +1214 MiB), and so is a progressive JPEG of that size. A baseline JPEG of the
same size is decoded at a reduced scale and taken, as is a PNG at the pixel limit, each in
under 300 MiB. A running studio answers the PNG, sent four times at once, with a 400 naming
the limit, and its server stays under 300 MiB."""

from __future__ import annotations

import io
from concurrent.futures import ThreadPoolExecutor

import pytest
from conftest import png_bytes, start_studio, stop_studio

from grassd.daemon.studio.views import MAX_IMAGE_PIXELS
from grassd.rigs.hostile_decodes import flat_png, run_child
from grassd.rigs.peak_memory import proc_mib

pytestmark = pytest.mark.timeout(300)

PEAK_MIB = 300.0

#: picture_levels of the file argv[1] for a display of argv[2] x argv[3] (the studio's decode).
DECODE = """
from pathlib import Path
from grassd.daemon.studio import views
levels = views.picture_levels(Path(sys.argv[1]).read_bytes(), int(sys.argv[2]),
                              int(sys.argv[3]))
out["shape"] = list(levels.shape)
"""


def _decode(tmp_path, data: bytes, rows: int = 8, cols: int = 8) -> dict:
    path = tmp_path / "picture"
    path.write_bytes(data)
    return run_child(DECODE, str(path), str(rows), str(cols))


@pytest.fixture(scope="module")
def huge_png() -> bytes:
    data = flat_png(8192, 8192)
    assert len(data) < 300 * 1024
    return data


def test_an_8192_x_8192_png_is_refused_from_its_header(tmp_path, huge_png):
    out = _decode(tmp_path, huge_png)
    print(f"\nPNG ({len(huge_png) / 1024:.0f} KiB) of 8192 x 8192: {out}")
    assert out.get("error") == "PictureTooLarge", out
    assert "8192 x 8192 = 67108864 pixels" in out["message"]
    assert f"at most {MAX_IMAGE_PIXELS}" in out["message"]
    assert out["peak_mib"] < PEAK_MIB, out


def test_a_jpeg_of_8192_x_8192_is_decoded_reduced(tmp_path):
    from PIL import Image

    buf = io.BytesIO()
    Image.new("L", (8192, 8192), 140).save(buf, "JPEG", quality=50)
    out = _decode(tmp_path, buf.getvalue(), rows=16, cols=32)
    print(f"\nJPEG ({buf.tell() / 1024:.0f} KiB) of 8192 x 8192: {out}")
    assert out.get("shape") == [16, 32], out
    assert out["peak_mib"] < PEAK_MIB, out


def test_a_progressive_jpeg_of_8192_x_8192_is_refused_from_its_header(tmp_path):
    """A progressive JPEG's decoder holds every DCT coefficient of the full size whatever
    scale it decodes at (473 MiB for this one, 4:4:4): it is judged at its full size."""
    from PIL import Image

    buf = io.BytesIO()
    Image.new("L", (8192, 8192), 140).save(buf, "JPEG", quality=50, progressive=True)
    out = _decode(tmp_path, buf.getvalue(), rows=16, cols=32)
    print(f"\nprogressive JPEG ({buf.tell() / 1024:.0f} KiB) of 8192 x 8192: {out}")
    assert out.get("error") == "PictureTooLarge", out
    assert "8192 x 8192 = 67108864 pixels" in out["message"]
    assert out["peak_mib"] < PEAK_MIB, out


def test_a_png_at_the_pixel_limit_is_taken(tmp_path):
    side = int(MAX_IMAGE_PIXELS ** 0.5)
    out = _decode(tmp_path, flat_png(side, side))
    print(f"\nPNG of {side} x {side}: {out}")
    assert out.get("shape") == [8, 8], out
    assert out["peak_mib"] < PEAK_MIB, out


def test_a_running_studio_refuses_four_at_once_in_little_memory(tmp_path, huge_png):
    import numpy as np

    studio = start_studio(tmp_path)
    try:
        pid = studio.proc.pid
        with open(f"/proc/{pid}/clear_refs", "w") as fh:  # VmHWM from now on
            fh.write("5")
        with ThreadPoolExecutor(4) as pool:
            answers = list(pool.map(lambda _: studio.request("api/picture", huge_png), range(4)))
        peak = proc_mib(pid, "VmHWM")
        print(f"\n4 x 8192 x 8192 PNG: {[s for s, _ in answers]}, server peak {peak:.0f} MiB")
        for status, body in answers:
            assert status in (400, 503), (status, body)  # 503: the studio's upload cap
        refused = [body for status, body in answers if status == 400]
        assert refused and all(f"at most {MAX_IMAGE_PIXELS}" in str(b) for b in refused)
        assert peak < PEAK_MIB, peak
        status, body = studio.request("api/picture", png_bytes(np.full((4, 8), 200)))
        assert status == 200, body
    finally:
        stop_studio(studio)
