"""``load_hdri(max_width=)`` reads a panorama wider than it needs band by band, box-filtered
as it is decoded: the result is the one :func:`downsample` gives on the whole map (EXR float
and half, a luminance-only EXR, Radiance RLE and flipped flat), and an 8192 x 4096 EXR or
Radiance file read to 2048 x 1024 keeps the process under 300 MiB (read whole and
downsampled, it took 2 GB). A map no small whole factor reduces is refused from its
header."""

from __future__ import annotations

import numpy as np
import OpenEXR
import pytest

from grassd.rigs.hostile_decodes import run_child
from grassd.rigs.inbox_fuzz import write_flat_exr, write_zero_exr
from grassd.rigs.peak_memory import refusal_cost
from grassd.sim import hdri
from grassd.sim.errors import HdriError

pytestmark = pytest.mark.timeout(120)

PEAK_MIB = 300.0

#: load_hdri(argv[1], max_width=2048): its shape and range.
REDUCED = """
from grassd.sim.hdri import load_hdri
img = load_hdri(sys.argv[1], max_width=2048)
out.update(shape=list(img.shape), min=float(img.min()), max=float(img.max()))
"""


def _map(h: int = 96, w: int = 192) -> np.ndarray:
    return np.random.default_rng(7).uniform(0.05, 3.0, (h, w, 3)).astype(np.float32)


def _flat_hdr(path, img: np.ndarray) -> None:
    """``img`` as a flat (not run-length) Radiance file stored bottom-up and right to left
    (``+Y H -X W``)."""
    h, w = img.shape[:2]
    rgbe = hdri._float_to_rgbe(img[::-1, ::-1])
    path.write_bytes(b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n" + f"+Y {h} -X {w}\n".encode()
                     + rgbe.tobytes())


def _rle_hdr(path, width: int, height: int) -> int:
    """A run-length Radiance file of ``width`` x ``height`` texels all 1.0, written scanline by
    scanline; its size in bytes."""
    runs = []
    for v in (128, 128, 128, 129):  # RGBE of 1.0: mantissa 128, exponent 129
        left, parts = width, []
        while left:
            n = min(127, left)
            parts.append(bytes((128 + n, v)))
            left -= n
        runs.append(b"".join(parts))
    comp = bytes((2, 2, width >> 8, width & 0xFF)) + b"".join(runs)
    data = (b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n" + f"-Y {height} +X {width}\n".encode()
            + comp * height)
    path.write_bytes(data)
    return len(data)


@pytest.mark.parametrize("band_texels", [192 * 3, 192 * 96 * 2])
def test_reduced_read_is_the_whole_maps_downsampling(tmp_path, monkeypatch, band_texels):
    monkeypatch.setattr(hdri, "_BAND_TEXELS", band_texels)  # many bands, or one
    img = _map()
    hdri.write_exr(tmp_path / "f.exr", img)
    hdri.write_exr(tmp_path / "h.exr", img, half=True)
    hdri.write_hdr(tmp_path / "r.hdr", img)
    _flat_hdr(tmp_path / "flipped.hdr", img)
    y = np.ascontiguousarray(img[..., 1])
    OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage},
                 {"Y": y}).write(str(tmp_path / "y.exr"))
    assert hdri.reduction_factor(192, 96, 64) == 3
    for name in ("f.exr", "h.exr", "r.hdr", "flipped.hdr", "y.exr"):
        whole = hdri.load_hdri(tmp_path / name)
        reduced = hdri.load_hdri(tmp_path / name, max_width=64)
        assert reduced.shape == (32, 64, 3) and reduced.dtype == np.float32
        np.testing.assert_allclose(reduced, hdri.downsample(whole, 3), rtol=1e-6, err_msg=name)
    assert hdri.load_hdri(tmp_path / "f.exr", max_width=192).shape == (96, 192, 3)  # fits


def _exr(path, img: np.ndarray, compression, tile: int | None = None) -> None:
    header = {"compression": compression, "type": OpenEXR.scanlineimage}
    if tile is not None:
        tiles = OpenEXR.TileDescription()
        tiles.xSize = tiles.ySize = tile
        header.update(type=OpenEXR.tiledimage, tiles=tiles)
    planes = {c: np.ascontiguousarray(img[..., i]) for i, c in enumerate("RGB")}
    OpenEXR.File(header, planes).write(str(path))


def test_tiles_and_chunks_are_read_whole_and_big_tiles_refused(tmp_path, monkeypatch):
    monkeypatch.setattr(hdri, "_BAND_TEXELS", 192 * 3)  # bands smaller than a chunk
    img = _map()
    _exr(tmp_path / "dwab.exr", img, OpenEXR.DWAB_COMPRESSION)  # 256 scanlines a chunk
    _exr(tmp_path / "tiled.exr", img, OpenEXR.ZIP_COMPRESSION, tile=32)
    _exr(tmp_path / "one_tile.exr", img, OpenEXR.ZIP_COMPRESSION, tile=192)
    for name in ("dwab.exr", "tiled.exr", "one_tile.exr"):
        np.testing.assert_allclose(hdri.load_hdri(tmp_path / name, max_width=64),
                                   hdri.downsample(hdri.load_hdri(tmp_path / name), 3),
                                   rtol=1e-6, err_msg=name)
    monkeypatch.setattr(hdri, "_MAX_BAND_TEXELS", 192 * 40)  # a band of 40 rows at most
    with pytest.raises(HdriError, match="OpenEXR tiles of 192 x 192: a band of 96 rows"):
        hdri.load_hdri(tmp_path / "one_tile.exr", max_width=96)  # the one tile: 96 rows
    assert hdri.load_hdri(tmp_path / "tiled.exr", max_width=96).shape == (48, 96, 3)  # 32


def test_8192_x_4096_exr_and_hdr_read_to_2048_in_little_memory(tmp_path):
    exr_bytes = write_flat_exr(tmp_path / "sky.exr", [("sky", 8192, 4096, ["B", "G", "R"])],
                               1.0)
    hdr_bytes = _rle_hdr(tmp_path / "sky.hdr", 8192, 4096)
    for name, size in (("sky.exr", exr_bytes), ("sky.hdr", hdr_bytes)):
        out = run_child(REDUCED, str(tmp_path / name))
        print(f"\n{name} ({size / 1024:.0f} KiB) of 8192 x 4096 read to 2048: {out}")
        assert out["shape"] == [1024, 2048, 3], out
        assert abs(out["min"] - 1.0) < 1e-2 and abs(out["max"] - 1.0) < 1e-2, out  # RGBE: 1/256
        assert out["peak_mib"] < PEAK_MIB, out


def test_a_map_no_small_factor_reduces_is_refused_from_its_header(tmp_path):
    path = tmp_path / "prime.exr"
    write_zero_exr(path, [("sky", 2 * 2053, 2053, ["B", "G", "R"])])  # 2053 is prime
    msg, seconds, rss = refusal_cost(lambda: hdri.load_hdri(path, max_width=2048), HdriError)
    assert "4106 x 2053 cannot be reduced by a small whole factor" in msg
    assert seconds < 3.0 and rss < 64 * 2**20, (seconds, rss)
