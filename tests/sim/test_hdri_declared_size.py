"""grassd.sim.hdri refuses a panorama from its headers, before decoding: a multi-part EXR whose
second part declares 16384 x 8192 (a valid 0.8 MB file that decodes to 768 MiB), an EXR with
203 channels (a valid 0.4 MB file that decodes to 812 MiB), a Radiance file whose resolution
line is huge or whose pixel data cannot fill it. Each refusal names the problem and takes
little time and memory."""

from __future__ import annotations

import os

import numpy as np
import OpenEXR
import pytest

from grassd.rigs.inbox_fuzz import write_zero_exr
from grassd.rigs.peak_memory import refusal_cost
from grassd.sim import hdri
from grassd.sim.errors import HdriError

pytestmark = pytest.mark.timeout(120)

MiB = 1 << 20


def refused(path, **kw) -> tuple[str, float, int]:
    """(error message, seconds, peak RSS growth in bytes) of loading ``path``, which must
    raise HdriError."""
    return refusal_cost(lambda: hdri.load_hdri(path, **kw), HdriError)


# ------------------------------------------------------------------------------ the writer


def test_the_handmade_writer_makes_files_openexr_decodes(tmp_path):
    write_zero_exr(tmp_path / "one.exr", [("rgb", 16, 8, ["R", "G", "B"])])
    write_zero_exr(tmp_path / "two.exr", [("rgb", 16, 8, ["R", "G", "B"]),
                                          ("more", 32, 4, ["R", "G", "B"])])
    one = OpenEXR.File(str(tmp_path / "one.exr"), separate_channels=True)
    assert one.channels()["R"].pixels.shape == (8, 16)
    two = OpenEXR.File(str(tmp_path / "two.exr"), separate_channels=True)
    assert [p.channels["G"].pixels.shape for p in two.parts] == [(8, 16), (4, 32)]
    assert not two.parts[1].channels["B"].pixels.any()


# ------------------------------------------------------------------------------ multi-part


def test_second_part_of_16384_x_8192_is_refused_from_the_headers(tmp_path):
    path = tmp_path / "two_parts.exr"
    size = write_zero_exr(path, [("rgb", 2048, 1024, ["R", "G", "B"]),
                                 ("big", 16384, 8192, ["R", "G", "B"])])
    assert size < 1 * MiB  # on disk; decoded, part 1 alone is 768 MiB of half floats
    msg, seconds, rss = refused(path)
    assert "multi-part OpenEXR with 2 parts" in msg
    assert "'big' 16384 x 8192" in msg
    assert "part 1 ('big') alone declares 16384 x 8192 = 134217728 texels" in msg
    assert "single part" in msg
    assert seconds < 3.0 and rss < 64 * MiB, (seconds, rss)
    print(f"\n2-part EXR ({size / 1e3:.0f} kB): refused in {seconds * 1e3:.0f} ms, "
          f"RSS +{rss / MiB:.1f} MiB")


def test_multi_part_file_of_small_parts_is_refused_too(tmp_path):
    path = tmp_path / "two_small.exr"
    write_zero_exr(path, [("left", 16, 8, ["R", "G", "B"]), ("right", 16, 8, ["R", "G", "B"])])
    msg, _, _ = refused(path)
    assert "2 parts ('left' 16 x 8, 'right' 16 x 8)" in msg


# ------------------------------------------------------------------------------ channels


def test_203_channels_are_refused_naming_them(tmp_path):
    path = tmp_path / "many.exr"
    junk = [f"junk.{i:03d}" for i in range(200)]
    size = write_zero_exr(path, [("many", 2048, 1024, ["R", "G", "B", *junk])])
    assert size < 1 * MiB  # decoded: 203 x 4 MiB = 812 MiB
    msg, seconds, rss = refused(path)
    assert "203 channels, 200 of them not a panorama's" in msg
    assert "'junk.000', 'junk.001'" in msg and "and 192 more" in msg
    assert "R, G, B (or Y)" in msg
    assert seconds < 3.0 and rss < 64 * MiB, (seconds, rss)
    print(f"\n203-channel EXR ({size / 1e3:.0f} kB): refused in {seconds * 1e3:.0f} ms, "
          f"RSS +{rss / MiB:.1f} MiB")


def test_one_extra_channel_is_named(tmp_path):
    img = np.ones((4, 8), np.float32)
    OpenEXR.File({}, {"R": img, "G": img, "B": img, "Z": img}).write(str(tmp_path / "z.exr"))
    msg, _, _ = refused(tmp_path / "z.exr")
    assert "4 channels, 1 of them not a panorama's ('Z')" in msg


@pytest.mark.parametrize("names", [("R", "G", "B", "A"), ("Y",), ("Y", "A")])
def test_rgb_y_and_alpha_are_accepted(tmp_path, names):
    img = np.linspace(0.1, 2.0, 32, dtype=np.float32).reshape(4, 8)
    OpenEXR.File({}, {n: img for n in names}).write(str(tmp_path / "ok.exr"))
    out = hdri.load_hdri(tmp_path / "ok.exr")
    np.testing.assert_array_equal(out[..., 0], img)


# ------------------------------------------------------------------------------ Radiance


def test_hdr_declaring_a_huge_size_is_refused_before_reading(tmp_path):
    path = tmp_path / "huge.hdr"
    path.write_bytes(b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 1000000 +X 2000000\n"
                     + b"\x02\x02\x00\x08" * 16)
    msg, seconds, rss = refused(path)
    assert "2000000 x 1000000 = 2000000000000 texels exceeds the limit" in msg
    assert seconds < 3.0 and rss < 16 * MiB, (seconds, rss)


def test_hdr_whose_data_cannot_fill_its_size_is_refused_before_allocating(tmp_path):
    path = tmp_path / "short.hdr"  # the largest size allowed, 20 bytes of pixels
    path.write_bytes(b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 4096 +X 8192\n"
                     + bytes((2, 2, 0x20, 0x00)) + b"\x80\x00" * 8)
    msg, seconds, rss = refused(path)
    assert "truncated Radiance pixel data" in msg and "needs at least" in msg
    assert seconds < 3.0 and rss < 64 * MiB, (seconds, rss)  # not the 128 MiB image


def test_a_fifo_is_refused_without_blocking(tmp_path):
    fifo = tmp_path / "pano.exr"
    os.mkfifo(fifo)
    msg, seconds, _ = refused(fifo)
    assert "not a regular file" in msg and seconds < 3.0
