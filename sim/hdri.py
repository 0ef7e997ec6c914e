"""Read, validate, write and downsample equirectangular HDR environment maps.

Files are OpenEXR (any compression the OpenEXR 3.x library reads; R, G, B channels in half or
float, or a single Y channel) or Radiance ``.hdr`` (RGBE or XYZE, flat or new-style run-length
encoded). Every loader returns linear Rec.709 RGB radiance (relative units, as stored in the
file) as a C-contiguous ``(H, W, 3)`` float32 array with ``W == 2 H``, row 0 at the top (zenith).
How such an array maps onto directions is defined in :mod:`grassd.sim.lighting`.

Colour: an EXR ``chromaticities`` attribute or a Radiance ``PRIMARIES=`` line that differs from
Rec.709/D65 is converted to linear Rec.709 with a Bradford adaptation to D65 (for the shared
Poly Haven maps, whose attribute holds the sRGB primaries adapted to D50, that conversion is the
identity within 1e-4 and is skipped). Radiance ``EXPOSURE=`` lines are divided out.

Checks (:func:`check_env`, run by :func:`load_hdri`) raises :class:`HdriError` with one
line naming the problem for: a missing, unreadable, truncated or corrupt file; a map that is not
2:1 or has fewer than :data:`MIN_HEIGHT` rows; more than ``max_texels`` texels (default
:data:`MAX_TEXELS`, checked from the header before any pixel is allocated); NaN or infinite
texels; negative texels beyond compression noise; no light above the horizon. A size over
``max_texels`` is :class:`~grassd.sim.errors.HdriTooLarge`; :func:`read_header` makes every
check that needs no pixel. A reader that uses a narrower map passes ``max_width`` to
:func:`load_hdri`: the map is then box-filtered band by band as it is decoded, never held
whole.

Negative texels: lossy EXR compression (DWAA/DWAB, used by the shared panoramas) rings around
bright features and leaves a few values slightly below zero. The noise scale is set by the map's
brightness, so the tolerance is relative to a robust scale of the map: a value ``x < 0`` with
``x >= -NEGATIVE_TOLERANCE * s`` is clamped to 0 (a warning gives the count), where ``s`` is the
90th percentile of the luminance (the bright part of the scene, unaffected by a sun of a few
texels; if that percentile is 0, the maximum luminance). On the shared maps the worst negative is
0.09 % of ``s`` (forest.exr: -2.2e-3 against s = 2.35), so ``NEGATIVE_TOLERANCE = 0.01`` leaves a
ten-fold margin, while a real sign or offset error (negatives of the order of the map's values)
is refused.
"""

from __future__ import annotations

import logging
import math
import os
import re
import stat
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

import numpy as np
import OpenEXR

from grassd.sim.errors import HdriError, HdriTooLarge
from grassd.sim.native_output import capture_native_output

__all__ = [
    "MAX_TEXELS",
    "RENDERER_TEXELS",
    "MIN_HEIGHT",
    "HdriHeader",
    "NEGATIVE_TOLERANCE",
    "REC709_LUMINANCE",
    "load_hdri",
    "read_header",
    "read_open_header",
    "reduction_factor",
    "check_env",
    "write_exr",
    "write_hdr",
    "downsample",
]

log = logging.getLogger(__name__)

#: Largest map accepted, in texels: 8192 x 4096 = 33.5 M texels, 400 MB as float32 RGB (the
#: loader briefly holds about three such arrays). Larger panoramas add nothing to a lux-scaled
#: light probe; downsample them (e.g. ``oiiotool in.exr --resize 4096x2048 -o out.exr``).
MAX_TEXELS: int = 8192 * 4096
#: Largest map the renderer holds, in texels (2048 x 1024; the default environment capacity of
#: :class:`grassd.sim.renderer.Capacity`): a reader that hands its map to the renderer
#: unreduced (the daemon's calibration) refuses a bigger one from its header.
RENDERER_TEXELS: int = 2048 * 1024
#: Smallest accepted height in rows (the width is twice this).
MIN_HEIGHT: int = 4
#: Negative texels down to -NEGATIVE_TOLERANCE x (90th percentile luminance) are clamped to 0.
NEGATIVE_TOLERANCE: float = 0.01
#: Rec.709 / sRGB luminance weights (Y row of the RGB -> XYZ matrix, D65).
REC709_LUMINANCE = np.array([0.2126, 0.7152, 0.0722])

_REC709_PRIMARIES = (0.64, 0.33, 0.30, 0.60, 0.15, 0.06)
_D65 = (0.3127, 0.3290)
_EXR_MAGIC = b"\x76\x2f\x31\x01"
#: The channels an OpenEXR panorama may have: colour (R, G, B or luminance Y) and alpha.
_EXR_CHANNELS = ("R", "G", "B", "A", "Y")
_BRADFORD = np.array(
    [[0.8951, 0.2664, -0.1614], [-0.7502, 1.7135, 0.0367], [0.0389, -0.0685, 1.0296]]
)


def default_site_hdri() -> Path:
    """The packaged panorama of the embedded default site (``grassd/sim/data/default_site.exr``,
    256 x 128 texels, linear Rec.709): the light of ``make demo``, of a daemon that has no
    bundle yet, of the simulated site camera and of a studio given no light."""
    from importlib import resources

    return Path(str(resources.files("grassd.sim").joinpath("data/default_site.exr")))


# ----------------------------------------------------------------------------------- colour


def _xyz_of(xy: tuple[float, float]) -> np.ndarray:
    x, y = xy
    return np.array([x / y, 1.0, (1.0 - x - y) / y])


def _rgb_to_xyz(primaries: tuple[float, ...], white: tuple[float, float]) -> np.ndarray:
    """Normalised primary matrix (SMPTE RP 177) of an RGB space."""
    cols = np.stack([_xyz_of(primaries[0:2]), _xyz_of(primaries[2:4]), _xyz_of(primaries[4:6])])
    scale = np.linalg.solve(cols.T, _xyz_of(white))
    return cols.T * scale


def _to_rec709_matrix(primaries: tuple[float, ...], white: tuple[float, float]) -> np.ndarray:
    """3x3 matrix taking linear RGB in (primaries, white) to linear Rec.709 (Bradford to D65)."""
    lms_src = _BRADFORD @ _xyz_of(white)
    lms_dst = _BRADFORD @ _xyz_of(_D65)
    cat = np.linalg.inv(_BRADFORD) @ np.diag(lms_dst / lms_src) @ _BRADFORD
    return np.linalg.inv(_rgb_to_xyz(_REC709_PRIMARIES, _D65)) @ cat @ _rgb_to_xyz(
        primaries, white
    )


def _apply_matrix(img: np.ndarray, matrix: np.ndarray, source: str) -> np.ndarray:
    if np.allclose(matrix, np.eye(3), atol=1e-3):
        return img
    log.info("%s: converting from the file's primaries to linear Rec.709", source)
    return np.einsum("hwc,rc->hwr", img, matrix.astype(np.float32), optimize=True)


# ------------------------------------------------------------------------------- validation


def _check_size(width: int, height: int, max_texels: int, source: str) -> None:
    if width <= 0 or height <= 0:
        raise HdriError(f"{source}: the header gives an empty image ({width} x {height})")
    if width * height > max_texels:
        raise HdriTooLarge(
            f"{source}: {width} x {height} = {width * height} texels exceeds the limit of "
            f"{max_texels} texels; nothing was decoded: downsample the panorama (e.g. to "
            "2048 x 1024)", width=width, height=height, limit=max_texels)
    if width != 2 * height:
        raise HdriError(
            f"{source}: {width} x {height} is not an equirectangular panorama; "
            "the width must be exactly twice the height (2:1)"
        )
    if height < MIN_HEIGHT:
        raise HdriError(f"{source}: {width} x {height} is too small; need at least "
                        f"{2 * MIN_HEIGHT} x {MIN_HEIGHT}")


#: The clamped maps already warned of in this process (source, count, lowest): a program that
#: reads one file again (the studio per request, a benchmark per setting) says it once.
_CLAMP_WARNED: set[tuple[str, int, float]] = set()


def check_env(img: np.ndarray, source: str = "environment map",
              max_texels: int = MAX_TEXELS, *, warn: bool = True) -> np.ndarray:
    """Check an equirectangular radiance map and return it as clean float32 (H, W, 3).

    Units are kept (relative or absolute linear Rec.709 radiance). Small negative texels from
    lossy compression are clamped to 0 with a warning (rule in the module docstring; once per
    map and process; ``warn`` False: none, for a check whose map another process uses); the
    input array is not modified. Raises :class:`HdriError` naming the problem otherwise.
    """
    arr = np.asarray(img)
    if arr.ndim != 3 or arr.shape[2] != 3:
        raise HdriError(f"{source}: expected an (H, W, 3) RGB array, got shape {arr.shape}")
    _check_size(arr.shape[1], arr.shape[0], max_texels, source)
    if not np.issubdtype(arr.dtype, np.floating):
        raise HdriError(f"{source}: texels must be floating point radiance, got {arr.dtype}")
    arr = np.ascontiguousarray(arr, dtype=np.float32)
    finite = np.isfinite(arr).all(axis=2)
    if not finite.all():
        bad = np.argwhere(~finite)
        row, col = bad[0]
        raise HdriError(
            f"{source}: {len(bad)} texel(s) hold NaN or infinity (first at row {row}, column "
            f"{col}); re-export the panorama"
        )
    lum = arr @ REC709_LUMINANCE.astype(np.float32)
    lowest = float(arr.min())
    if lowest < 0.0:
        scale = float(np.percentile(lum, 90.0))
        if scale <= 0.0:
            scale = float(lum.max())
        tolerance = NEGATIVE_TOLERANCE * scale
        if lowest < -tolerance:
            count = int((arr < -tolerance).sum())
            raise HdriError(
                f"{source}: {count} texel value(s) are negative beyond compression noise "
                f"(lowest {lowest:.4g}, tolerance {-tolerance:.4g} = -{NEGATIVE_TOLERANCE} x "
                "90th-percentile luminance); the file is not plain radiance"
            )
        count = int((arr < 0.0).sum())
        if warn and (source, count, lowest) not in _CLAMP_WARNED:  # once per map and process
            _CLAMP_WARNED.add((source, count, lowest))
            log.warning("%s: clamped %d slightly negative texel value(s) (lowest %.3g, "
                        "compression noise) to 0", source, count, lowest)
        arr = np.maximum(arr, 0.0)
        lum = np.maximum(lum, 0.0)
    upper_rows = (arr.shape[0] + 1) // 2  # every row whose band reaches above the horizon
    if not (lum[:upper_rows] > 0.0).any():
        raise HdriError(
            f"{source}: the upper hemisphere is black (no light above the horizon); check that "
            "the panorama is not upside down or empty"
        )
    return arr


# ------------------------------------------------------------------------------------ load


@dataclass(frozen=True)
class HdriHeader:
    """What a panorama's header declares: ``width`` x ``height`` texels and its ``format``
    ("OpenEXR" or "Radiance")."""

    width: int
    height: int
    format: str


def _magic(p: Path) -> bytes:
    """The first 16 bytes of a regular file ``p`` (HdriError: missing, not regular, unreadable,
    empty)."""
    source = str(p)
    if not p.exists():
        raise HdriError(f"HDRI file {source} does not exist")
    if not p.is_file():
        raise HdriError(f"HDRI path {source} is not a regular file")
    try:  # non-blocking: a FIFO swapped in after the check above must not hang the read
        fd = os.open(p, os.O_RDONLY | os.O_NONBLOCK)
        with os.fdopen(fd, "rb") as fh:
            if not stat.S_ISREG(os.fstat(fh.fileno()).st_mode):
                raise HdriError(f"HDRI path {source} is not a regular file")
            magic = fh.read(16)
    except OSError as exc:
        raise HdriError(f"cannot read HDRI file {source}: {exc.strerror or exc}") from exc
    return _checked_magic(magic, source)


def _checked_magic(magic: bytes, source: str) -> bytes:
    """``magic`` (a file's first 16 bytes) when it opens an OpenEXR or Radiance file."""
    if not magic:
        raise HdriError(f"{source}: the file is empty")
    if magic[:4] != _EXR_MAGIC and not magic.startswith(b"#?"):
        raise HdriError(
            f"{source}: neither OpenEXR nor Radiance .hdr (unrecognised first bytes); "
            "convert the panorama to .exr"
        )
    return magic


def read_header(path: str | os.PathLike, max_texels: int = MAX_TEXELS) -> HdriHeader:
    """Read and check a panorama's header alone: every check :func:`load_hdri` makes before
    it decodes a pixel (a regular OpenEXR or Radiance file, one part, a panorama's channels,
    2:1, at least :data:`MIN_HEIGHT` rows, at most ``max_texels`` texels). Reads a few
    kilobytes whatever the file declares.

    Raises:
        HdriTooLarge: more than ``max_texels`` texels (the message names both).
        HdriError: any other problem, named.
    """
    p = Path(path)
    _magic(p)  # a regular file, readable, of a known kind: named errors before it is opened
    with p.open("rb") as fh:
        return read_open_header(fh, str(p), max_texels)


def read_open_header(fh: BinaryIO, source: str, max_texels: int = MAX_TEXELS) -> HdriHeader:
    """:func:`read_header` of a panorama already open as ``fh`` (binary, seekable; read from
    its start, left at no particular position), so that a caller holding the file's
    descriptor checks the header it hashed without opening the file again. ``source`` names
    the file in errors. Raises as :func:`read_header`."""
    fh.seek(0)
    magic = _checked_magic(fh.read(16), source)
    fh.seek(0)
    if magic[:4] == _EXR_MAGIC:
        width, height, _ = _exr_header(source, max_texels, fh)
        return HdriHeader(width, height, "OpenEXR")
    head = _hdr_header(fh, source, max_texels)
    return HdriHeader(head.width, head.height, "Radiance")


def load_hdri(path: str | os.PathLike, max_texels: int = MAX_TEXELS, *,
              warn: bool = True, max_width: int | None = None) -> np.ndarray:
    """Load an equirectangular HDRI (.exr or Radiance .hdr) as validated linear Rec.709 RGB.

    Returns a C-contiguous (H, W, 3) float32 array of relative radiance, row 0 = zenith, with
    W = 2 H. The format is recognised from the file's first bytes, not its name. The size is
    checked against ``max_texels`` from the header before pixels are read
    (:func:`read_header`; :class:`~grassd.sim.errors.HdriTooLarge` when over). ``warn``: as
    :func:`check_env`.

    ``max_width`` [texels]: a wider map is box-filtered down by the smallest whole factor
    that divides both sides and makes it at most that wide (:func:`reduction_factor`; the
    power-preserving filter of :func:`downsample`) band by band as it is decoded, so the
    full-size map is never held (an 8192 x 4096 EXR read to 2048 x 1024 holds a few MiB of it
    at a time); HdriError when no such factor exists. :func:`check_env`'s checks are then
    made on the reduced map (its negative-noise tolerance judged there).
    """
    p = Path(path)
    exr = _magic(p)[:4] == _EXR_MAGIC
    if max_width is not None:
        head = read_header(p, max_texels)
        factor = reduction_factor(head.width, head.height, max_width, str(p))
        if factor > 1:
            img = _read_reduced(p, exr, factor, max_texels)
            return check_env(img, str(p), max_texels, warn=warn)
    img = _read_exr(p, max_texels) if exr else _read_hdr(p, max_texels)
    return check_env(img, str(p), max_texels, warn=warn)


def reduction_factor(width: int, height: int, max_width: int, source: str = "map") -> int:
    """The smallest whole factor that divides ``width`` and ``height`` and makes the width at
    most ``max_width`` texels (1 when it already is). HdriError when there is none that
    leaves :data:`MIN_HEIGHT` rows and whose band of ``factor`` rows holds at most
    :data:`_MAX_BAND_TEXELS` texels (e.g. a prime height)."""
    if width <= max_width:
        return 1
    for factor in range(-(-width // max_width), width + 1):
        if factor * width > _MAX_BAND_TEXELS or height // factor < MIN_HEIGHT:
            break
        if width % factor == 0 and height % factor == 0:
            return factor
    raise HdriError(f"{source}: {width} x {height} cannot be reduced by a small whole factor "
                    f"to at most {max_width} texels wide; resize it to {max_width} x "
                    f"{max_width // 2}")


#: Texels of the full-size map decoded at once by a reduced read (:func:`load_hdri`), and the
#: most a band of ``factor`` rows may hold.
_BAND_TEXELS = 1 << 19
_MAX_BAND_TEXELS = 1 << 21


def _read_reduced(p: Path, exr: bool, factor: int, max_texels: int) -> np.ndarray:
    """The map at ``p`` box-filtered by ``factor`` band by band (float32 (H/f, W/f, 3))."""
    source = str(p)
    bands = _exr_bands if exr else _hdr_bands
    out: np.ndarray | None = None
    edges = None
    for row0, band, height in bands(p, max_texels, factor):
        if out is None:
            out = np.empty((height // factor, band.shape[1] // factor, 3), np.float32)
            edges = np.cos(np.pi * np.arange(height + 1) / height)
        if not np.isfinite(band).all():
            bad = np.argwhere(~np.isfinite(band).all(axis=2))
            raise HdriError(f"{source}: texel(s) hold NaN or infinity (first at row "
                            f"{row0 + bad[0][0]}, column {bad[0][1]}); re-export the panorama")
        step = _band_rows(band.shape[1], factor, band.shape[0]) // 4 // factor * factor
        for a in range(0, band.shape[0], max(factor, step)):  # float64 a quarter band at a time
            b = min(band.shape[0], a + max(factor, step))
            omega = edges[row0 + a: row0 + b] - edges[row0 + a + 1: row0 + b + 1]
            out[(row0 + a) // factor: (row0 + b) // factor] = _box(band[a:b], factor, omega)
    if out is None:
        raise HdriError(f"{source}: the file holds no pixel rows")
    return out


def _box(band: np.ndarray, factor: int, omega: np.ndarray) -> np.ndarray:
    """Rows of ``band`` (r, W, C), ``r`` a multiple of ``factor``, box-filtered by ``factor``
    with row weights ``omega`` (r,) (each row's solid angle), as float32 (r/f, W/f, C)."""
    r, w, c = band.shape
    om = np.asarray(omega, np.float64).reshape(r // factor, factor, 1, 1, 1)
    blocks = np.asarray(band, np.float64).reshape(r // factor, factor, w // factor, factor, c)
    weight = om.sum(axis=1).reshape(r // factor, 1, 1) * factor
    return ((blocks * om).sum(axis=(1, 3)) / weight).astype(np.float32)


def _band_rows(width: int, unit: int, height: int) -> int:
    """Rows of a band: a multiple of ``unit`` rows near :data:`_BAND_TEXELS` texels."""
    return min(height, max(unit, (_BAND_TEXELS // width) // unit * unit))


#: Scanlines an OpenEXR chunk holds, by compression (OpenEXR's own table; another: 256): a
#: band is read in whole chunks, so that none is decompressed twice.
_EXR_CHUNK_LINES = {"NO_COMPRESSION": 1, "RLE_COMPRESSION": 1, "ZIPS_COMPRESSION": 1,
                    "ZIP_COMPRESSION": 16, "PXR24_COMPRESSION": 16, "PIZ_COMPRESSION": 32,
                    "B44_COMPRESSION": 32, "B44A_COMPRESSION": 32, "DWAA_COMPRESSION": 32,
                    "HTJ2K32_COMPRESSION": 32, "DWAB_COMPRESSION": 256,
                    "HTJ2K256_COMPRESSION": 256}


def _exr_band_unit(source: str, header: dict, width: int, height: int, factor: int) -> int:
    """Rows a band of a reduced EXR read is a multiple of: whole ``factor`` blocks, whole
    chunks, and whole rows of tiles (the library decodes a row of tiles at once). HdriError
    when such a band would hold more than :data:`_MAX_BAND_TEXELS` texels (tiles of
    thousands of rows)."""
    tiles = header.get("tiles")
    if tiles is not None:
        lines = int(tiles.ySize)
    else:
        name = getattr(header.get("compression"), "name", "")
        lines = _EXR_CHUNK_LINES.get(name, 256)
    unit = min(height, math.lcm(factor, max(1, lines)))
    if unit * width > _MAX_BAND_TEXELS:
        what = (f"tiles of {tiles.xSize} x {tiles.ySize}" if tiles is not None
                else f"chunks of {lines} scanlines")
        raise HdriError(f"{source}: OpenEXR {what}: a band of {unit} rows of {width} texels "
                        f"is more than the {_MAX_BAND_TEXELS} a reduced read holds; re-export "
                        "it as scanlines (or with tiles of at most 256 rows)")
    return unit


def _header_text(v: object, max_chars: int = 64) -> str:
    """A name from a file's header as it may appear in a message: repr (controls escaped,
    one line), cut to ``max_chars`` characters (a header may hold kilobytes of name)."""
    text = repr(str(v))
    return text if len(text) <= max_chars else text[:max_chars] + "...'"


def _part_summary(parts: list) -> str:
    """``'name' W x H`` of each part (the first few), for an error message."""
    shown = [f"{name} {w} x {h}" for name, w, h, _ in parts[:4]]
    more = f" and {len(parts) - 4} more" if len(parts) > 4 else ""
    return ", ".join(shown) + more


def _exr_parts(source: str, fh: BinaryIO | None = None) -> list[tuple[str, int, int, dict]]:
    """(name, width, height, header) of every part of an OpenEXR file (``fh``: already open
    at its start, else opened by name), from its headers alone (no pixel is read)."""
    headers = _exr_call(source, "header", lambda: [
        part.header for part in (_exr_file(source, header_only=True) if fh is None
                                 else OpenEXR.File(fh, header_only=True)).parts])
    out = []
    for i, header in enumerate(headers):
        if "dataWindow" not in header:
            raise HdriError(f"{source}: OpenEXR part {i} lacks a dataWindow")
        (x0, y0), (x1, y1) = header["dataWindow"]
        name = _header_text(header.get("name") or f"part {i}")
        out.append((name, int(x1) - int(x0) + 1, int(y1) - int(y0) + 1, header))
    if not out:
        raise HdriError(f"{source}: the OpenEXR file has no part")
    return out


def _check_exr_channels(source: str, header: dict) -> list[str]:
    """The channel names of a panorama's header; raises HdriError for any channel other than
    R, G, B, A and Y (named in the message), for neither R, G, B nor Y, or a subsampled one."""
    chans = list(header.get("channels", []))
    names = [str(ch.name) for ch in chans]
    extra = sorted(set(names) - set(_EXR_CHANNELS))
    if extra:
        shown = ", ".join(_header_text(n) for n in extra[:8]) + (
            f" and {len(extra) - 8} more" if len(extra) > 8 else "")
        raise HdriError(
            f"{source}: {len(names)} channels, {len(extra)} of them not a panorama's "
            f"({shown}); an environment map has R, G, B (or Y) and optionally A: export "
            "only those (e.g. oiiotool in.exr --ch R,G,B -o out.exr)")
    if not ({"R", "G", "B"} <= set(names) or "Y" in names):
        raise HdriError(f"{source}: no R, G, B (or Y) channels; the file has "
                        f"{', '.join(_header_text(n) for n in sorted(names)[:8])}")
    for ch in chans:
        if getattr(ch, "xSampling", 1) != 1 or getattr(ch, "ySampling", 1) != 1:
            raise HdriError(f"{source}: channel {ch.name} is subsampled; save full-resolution RGB")
    return names


def _exr_header(source: str, max_texels: int, fh: BinaryIO | None = None
                ) -> tuple[int, int, dict]:
    """(width, height, header) of a single-part OpenEXR panorama (``fh``: as
    :func:`_exr_parts`), checked from its headers (parts, size, kind, channels); no pixel is
    read."""
    parts = _exr_parts(source, fh)
    if len(parts) != 1:  # refused from the headers: every part's size is named, none decoded
        over = [f"part {i} ({name}) alone declares {w} x {h} = {w * h} texels, over the "
                f"limit of {max_texels}" for i, (name, w, h, _) in enumerate(parts)
                if w > 0 and h > 0 and w * h > max_texels]
        raise HdriError(
            f"{source}: a multi-part OpenEXR with {len(parts)} parts ({_part_summary(parts)})"
            + (f"; {over[0]}" if over else "") + "; a panorama is a single part: re-export "
            "it alone (e.g. oiiotool in.exr --subimage 0 -o out.exr)")
    _, width, height, header = parts[0]
    _check_size(width, height, max_texels, source)
    kind = str(header.get("type", ""))
    if "deep" in kind:
        raise HdriError(f"{source}: deep OpenEXR images are not environment maps")
    _check_exr_channels(source, header)
    return width, height, header


def _read_exr(p: Path, max_texels: int) -> np.ndarray:
    source = str(p)
    width, height, header = _exr_header(source, max_texels)
    channels = _exr_call(source, "pixel data",
                         lambda: OpenEXR.File(source, separate_channels=True).channels())
    names = set(channels)
    if {"R", "G", "B"} <= names:
        planes = [channels[n].pixels for n in ("R", "G", "B")]
    elif "Y" in names:
        planes = [channels["Y"].pixels] * 3
    else:
        raise HdriError(f"{source}: no R, G, B (or Y) channels; the file has "
                        f"{', '.join(_header_text(n) for n in sorted(names)[:8])}")
    for plane in planes:
        if plane.shape != (height, width):
            raise HdriError(f"{source}: channel data {plane.shape} disagrees with the header's "
                            f"dataWindow {height} x {width}")
        if not np.issubdtype(plane.dtype, np.floating):
            raise HdriError(f"{source}: channels are {plane.dtype}, not half or float radiance")
    return _exr_colour(np.stack(planes, axis=-1).astype(np.float32), header, source)


def _exr_colour(img: np.ndarray, header: dict, source: str) -> np.ndarray:
    """Texels of an EXR with ``header`` (RGB, float32) in linear Rec.709."""
    chroma = header.get("chromaticities")
    if chroma is not None:
        chroma = tuple(float(c) for c in chroma)
        img = _apply_matrix(img, _to_rec709_matrix(chroma[:6], chroma[6:8]), source)
    return img


def _exr_bands(p: Path, max_texels: int, factor: int):
    """(first row, float32 RGB rows (r, W, 3) in linear Rec.709, height) of a single-part
    scanline or tiled EXR, band by band from the top; the header is checked first."""
    import Imath

    source = str(p)
    width, height, header = _exr_header(source, max_texels)
    names = [n for n in ("R", "G", "B") if n in _check_exr_channels(source, header)]
    names = names if len(names) == 3 else ["Y"] * 3
    as_float = Imath.PixelType(Imath.PixelType.FLOAT)
    infile = _exr_call(source, "header", lambda: OpenEXR.InputFile(source))
    try:
        types = infile.header()["channels"]
        if any(types[n].type.v == Imath.PixelType.UINT for n in set(names)):
            raise HdriError(f"{source}: channels are unsigned integers, not half or float "
                            "radiance")
        y_min = int(header["dataWindow"][0][1])
        rows = _band_rows(width, _exr_band_unit(source, header, width, height, factor), height)
        for row0 in range(0, height, rows):
            r = min(rows, height - row0)
            y0, y1 = y_min + row0, y_min + row0 + r - 1

            def read(y0=y0, y1=y1):
                return {n: infile.channel(n, as_float, y0, y1) for n in set(names)}

            raw = _exr_call(source, "pixel data", read)
            planes = [np.frombuffer(raw[n], np.float32) for n in names]
            if any(pl.size != r * width for pl in planes):
                raise HdriError(f"{source}: channel data disagrees with the header's "
                                f"dataWindow {height} x {width}")
            band = np.stack([pl.reshape(r, width) for pl in planes], axis=-1)
            yield row0, _exr_colour(band, header, source), height
    finally:
        infile.close()


def _exr_file(source: str, **kw) -> OpenEXR.File:
    """``OpenEXR.File`` of the file ``source`` read through a Python file object: a name
    that is not valid UTF-8 opens too, and a header-only read takes the header's bytes alone.
    (The pixels are read by name: the library's messages then name the file.)"""
    with open(source, "rb") as fh:
        return OpenEXR.File(fh, **kw)


def _exr_call(source: str, what: str, read):
    """``read()`` with OpenEXR's own messages on fd 1/2 captured (the user sees only our
    one-line error; the library's most specific EXR_ERR line goes into it)."""
    failure: Exception | None = None
    with capture_native_output() as native:
        try:
            return read()
        except Exception as exc:  # the binding raises RuntimeError/ValueError for bad files
            failure = exc
    detail = native.reason(source) or str(failure)  # the binding's text is often generic
    raise HdriError(f"{source}: corrupt or truncated OpenEXR {what} ({detail}); re-copy the "
                    "file or export it again") from failure


# Radiance RGBE ---------------------------------------------------------------------------

_RES_RE = re.compile(rb"^([-+])([XY]) (\d+) ([-+])([XY]) (\d+)$")
_RUN_BYTES = [bytes([v]) * 128 for v in range(256)]


@dataclass(frozen=True)
class _HdrHead:
    """A Radiance header as parsed: size, FORMAT, EXPOSURE product, PRIMARIES (or None), the
    resolution line's signs (``y_sign`` "+": stored bottom-up; ``x_sign`` "-": right to left),
    and the offset of the first pixel byte."""

    width: int
    height: int
    fmt: bytes
    exposure: float
    primaries: tuple[float, ...] | None
    y_sign: bytes
    x_sign: bytes
    data_at: int


def _hdr_header(fh, source: str, max_texels: int) -> _HdrHead:
    """Parse and check the header of the Radiance file open as ``fh`` (reads at most 64 KiB)."""
    head = fh.read(65536)
    end = head.find(b"\n\n")
    if end < 0:
        raise HdriError(f"{source}: Radiance header has no blank line before the resolution "
                        "(truncated or not an .hdr file)")
    nl = head.find(b"\n", end + 2)
    if nl < 0:
        raise HdriError(f"{source}: Radiance resolution line is missing (truncated file)")
    lines = head[:end].split(b"\n")
    res = head[end + 2: nl].strip()
    fmt, exposure, primaries = b"32-bit_rle_rgbe", 1.0, None
    for line in lines[1:]:
        if line.startswith(b"FORMAT="):
            fmt = line[7:].strip()
        elif line.startswith(b"EXPOSURE="):
            try:
                exposure *= float(line[9:])
            except ValueError as exc:
                raise HdriError(f"{source}: bad EXPOSURE line {line!r}") from exc
        elif line.startswith(b"PRIMARIES="):
            try:
                primaries = tuple(float(v) for v in line[10:].split())
            except ValueError as exc:
                raise HdriError(f"{source}: bad PRIMARIES line {line!r}") from exc
            if len(primaries) != 8:
                raise HdriError(f"{source}: PRIMARIES needs 8 numbers, got {line!r}")
    if fmt not in (b"32-bit_rle_rgbe", b"32-bit_rle_xyze"):
        raise HdriError(f"{source}: unsupported Radiance FORMAT {fmt.decode(errors='replace')}")
    m = _RES_RE.match(res)
    if m is None or m.group(2) != b"Y" or m.group(5) != b"X":
        raise HdriError(f"{source}: unsupported or corrupt resolution line {res!r} "
                        "(expected e.g. '-Y 512 +X 1024')")
    height, width = int(m.group(3)), int(m.group(6))
    _check_size(width, height, max_texels, source)
    if not exposure > 0.0 or not np.isfinite(exposure):
        raise HdriError(f"{source}: EXPOSURE product {exposure} is not positive")
    return _HdrHead(width, height, fmt, exposure, primaries, m.group(1), m.group(4), nl + 1)


def _read_hdr(p: Path, max_texels: int) -> np.ndarray:
    source = str(p)
    with p.open("rb") as fh:
        h = _hdr_header(fh, source, max_texels)
        height, width = h.height, h.width
        fh.seek(h.data_at)
        # RLE can at worst double the flat size (1-byte literals); never read more than that
        data = fh.read(height * (4 + 8 * width))
    return _hdr_float(_hdr_oriented(_decode_rgbe(data, height, width, source), h), h, source)


def _hdr_oriented(rgbe: np.ndarray, h: _HdrHead) -> np.ndarray:
    """The RGBE texels (H, W, 4) of a Radiance file row 0 at the top, column 0 at the left
    (a view)."""
    if h.y_sign == b"+":  # stored bottom-up
        rgbe = rgbe[::-1]
    if h.x_sign == b"-":  # stored right-to-left
        rgbe = rgbe[:, ::-1]
    return rgbe


def _hdr_float(rgbe: np.ndarray, h: _HdrHead, source: str) -> np.ndarray:
    """RGBE texels of a Radiance file with header ``h`` as float32 linear Rec.709."""
    img = _rgbe_to_float(rgbe) / np.float32(h.exposure)
    if h.fmt == b"32-bit_rle_xyze":
        to709 = np.linalg.inv(_rgb_to_xyz(_REC709_PRIMARIES, _D65))
        img = np.einsum("hwc,rc->hwr", img, to709.astype(np.float32), optimize=True)
    elif h.primaries is not None:
        img = _apply_matrix(img, _to_rec709_matrix(h.primaries[:6], h.primaries[6:]), source)
    return np.ascontiguousarray(img, dtype=np.float32)


def _hdr_bands(p: Path, max_texels: int, factor: int):
    """As :func:`_exr_bands` for a Radiance file, its bands decoded in file order (from the
    bottom for a file stored bottom-up)."""
    source = str(p)
    with p.open("rb") as fh:
        h = _hdr_header(fh, source, max_texels)
        fh.seek(h.data_at)
        data = fh.read(h.height * (4 + 8 * h.width))
    rows = _band_rows(h.width, factor, h.height)
    for y0, band in _rgbe_bands(data, h.height, h.width, source, rows):
        row0 = y0
        if h.y_sign == b"+":  # stored bottom-up: file rows y0.. are image rows H - y0 - r..
            row0, band = h.height - y0 - band.shape[0], band[::-1]
        if h.x_sign == b"-":
            band = band[:, ::-1]
        yield row0, _hdr_float(band, h, source), h.height


def _decode_rgbe(data: bytes, height: int, width: int, source: str) -> np.ndarray:
    """Decode the RGBE pixel stream (flat or new-style RLE) into (H, W, 4) uint8."""
    return next(_rgbe_bands(data, height, width, source, height))[1]


def _rgbe_bands(data: bytes, height: int, width: int, source: str, rows: int):
    """Decode the RGBE pixel stream (flat or new-style RLE) ``rows`` scanlines at a time, in
    file order: (first scanline, (r, W, 4) uint8) of each band."""
    new_rle = (
        8 <= width <= 0x7FFF and len(data) >= 4 and data[0] == 2 and data[1] == 2
        and (data[2] << 8 | data[3]) == width
    )
    if not new_rle:
        need = 4 * width * height
        if len(data) < need:
            raise HdriError(f"{source}: truncated Radiance pixel data ({len(data)} of {need} "
                            "bytes)")
        px = np.frombuffer(data, np.uint8, need).reshape(height, width, 4)
        for y0 in range(0, height, rows):
            band = px[y0: y0 + rows]
            if ((band[..., 0] == 1) & (band[..., 1] == 1) & (band[..., 2] == 1)).any():
                raise HdriError(f"{source}: old-style Radiance run-length encoding is not "
                                "supported; re-save the file (e.g. with oiiotool) as .exr or "
                                "new-style .hdr")
            yield y0, band
        return
    least = height * (4 + 4 * 2 * -(-width // 127))  # every scanline in runs of 127
    if len(data) < least:  # before allocating the image
        raise HdriError(f"{source}: truncated Radiance pixel data ({len(data)} bytes; "
                        f"{width} x {height} run-length encoded needs at least {least})")
    pos, n_data = 0, len(data)
    marker = bytes((2, 2, width >> 8, width & 0xFF))
    runs = _RUN_BYTES
    for y0 in range(0, height, rows):
        r = min(rows, height - y0)
        out = bytearray(4 * width * r)
        for y in range(y0, y0 + r):
            if data[pos: pos + 4] != marker:
                what = "truncated" if pos + 4 > n_data else "corrupt"
                raise HdriError(f"{source}: {what} Radiance pixel data at scanline {y} of "
                                f"{height}")
            pos += 4
            for c in range(4):
                off = ((y - y0) * 4 + c) * width
                end = off + width
                while off < end:
                    if pos >= n_data:
                        raise HdriError(f"{source}: truncated Radiance pixel data at scanline "
                                        f"{y} of {height}")
                    n = data[pos]
                    if n > 128:
                        n -= 128
                        if off + n > end or pos + 1 >= n_data:
                            raise HdriError(f"{source}: corrupt run-length data at scanline "
                                            f"{y}")
                        out[off: off + n] = runs[data[pos + 1]][:n]
                        pos += 2
                    else:
                        if n == 0 or off + n > end or pos + 1 + n > n_data:
                            raise HdriError(f"{source}: corrupt or truncated run-length data "
                                            f"at scanline {y}")
                        out[off: off + n] = data[pos + 1: pos + 1 + n]
                        pos += 1 + n
                    off += n
        yield y0, np.frombuffer(out, np.uint8).reshape(r, 4, width).transpose(0, 2, 1)


def _rgbe_to_float(rgbe: np.ndarray) -> np.ndarray:
    """RGBE bytes -> float32 RGB, as Radiance's colr_color: (m + 0.5) * 2**(e - 136)."""
    e = rgbe[..., 3].astype(np.int32)
    f = np.where(e > 0, np.ldexp(np.float32(1.0), e - 136), np.float32(0.0)).astype(np.float32)
    return (rgbe[..., :3].astype(np.float32) + np.float32(0.5)) * f[..., None]


def _float_to_rgbe(img: np.ndarray) -> np.ndarray:
    """float RGB (>= 0) -> RGBE bytes, as Radiance's setcolr (mantissa truncated)."""
    rgb = np.maximum(np.asarray(img, np.float64), 0.0)
    top = rgb.max(axis=-1)
    mant, expo = np.frexp(top)
    small = top < 1e-38
    scale = np.where(small, 0.0, mant * 256.0 / np.where(small, 1.0, top))
    out = np.empty(rgb.shape[:-1] + (4,), np.uint8)
    out[..., :3] = np.clip(np.floor(rgb * scale[..., None]), 0, 255).astype(np.uint8)
    out[..., 3] = np.where(small, 0, expo + 128).astype(np.uint8)
    return out


def _rle_encode_row(row: np.ndarray) -> bytes:
    """New-style RLE of one component of one scanline: runs >= 3 as runs, the rest literal."""
    n = row.size
    starts = np.flatnonzero(np.concatenate(([True], row[1:] != row[:-1])))
    lengths = np.diff(np.append(starts, n))
    parts: list[bytes] = []
    raw = row.tobytes()
    lit_start = 0
    for s, length in zip(starts.tolist(), lengths.tolist(), strict=True):
        if length < 3:
            continue
        for a in range(lit_start, s, 128):
            chunk = raw[a: min(a + 128, s)]
            parts.append(bytes((len(chunk),)) + chunk)
        v = raw[s]
        left = length
        while left > 0:
            k = min(left, 127)
            parts.append(bytes((128 + k, v)))
            left -= k
        lit_start = s + length
    for a in range(lit_start, n, 128):
        chunk = raw[a: min(a + 128, n)]
        parts.append(bytes((len(chunk),)) + chunk)
    return b"".join(parts)


# ----------------------------------------------------------------------------------- write


def _atomic_write(path: Path, writer) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=path.suffix, dir=path.parent)
    os.close(fd)
    try:
        writer(tmp)
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)  # mkstemp makes 0600; give the usual file mode
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def _as_rgb(img: np.ndarray) -> np.ndarray:
    arr = np.asarray(img)
    if arr.ndim != 3 or arr.shape[2] != 3:
        raise HdriError(f"cannot write an image of shape {arr.shape}; expected (H, W, 3) RGB")
    return arr


def write_exr(path: str | os.PathLike, img: np.ndarray, half: bool = False) -> None:
    """Write linear Rec.709 RGB (H, W, 3) as a ZIP-compressed scanline OpenEXR (atomically).

    Channels R, G, B in float32 (or half with ``half=True``); the Rec.709/D65 chromaticities
    attribute is set so other tools read the primaries right.
    """
    arr = _as_rgb(img)
    dtype = np.float16 if half else np.float32
    planes = {c: np.ascontiguousarray(arr[..., i], dtype=dtype) for i, c in enumerate("RGB")}
    header = {
        "compression": OpenEXR.ZIP_COMPRESSION,
        "type": OpenEXR.scanlineimage,
        "chromaticities": tuple(float(v) for v in _REC709_PRIMARIES + _D65),
    }
    _atomic_write(Path(path), lambda tmp: OpenEXR.File(header, planes).write(tmp))


def write_hdr(path: str | os.PathLike, img: np.ndarray, rle: bool = True) -> None:
    """Write linear RGB (H, W, 3) as a Radiance RGBE .hdr file (atomically).

    Negative values are written as 0. ``rle=True`` writes new-style run-length encoded scanlines
    (widths 8..32767; others are written flat), ``rle=False`` flat RGBE quadruples. Precision of
    RGBE: each component is stored to within 1/256 of the texel's largest component.
    """
    arr = _as_rgb(img)
    if not np.isfinite(arr).all():
        raise HdriError("cannot write NaN or infinite texels to a Radiance file")
    if float(np.max(arr, initial=0.0)) >= 2.0 ** 127:
        raise HdriError("texel values above 2**127 do not fit in RGBE")
    height, width = arr.shape[:2]
    rgbe = _float_to_rgbe(arr)
    header = (b"#?RADIANCE\n# written by grassd.sim.hdri\nFORMAT=32-bit_rle_rgbe\n\n"
              + f"-Y {height} +X {width}\n".encode())
    if rle and 8 <= width <= 0x7FFF:
        marker = bytes((2, 2, width >> 8, width & 0xFF))
        body = b"".join(
            marker + b"".join(_rle_encode_row(rgbe[y, :, c]) for c in range(4))
            for y in range(height)
        )
    else:
        body = rgbe.tobytes()

    def _write(tmp: str) -> None:
        with open(tmp, "wb") as fh:
            fh.write(header)
            fh.write(body)

    _atomic_write(Path(path), _write)


# ------------------------------------------------------------------------------ downsample


def downsample(img: np.ndarray, factor: int) -> np.ndarray:
    """Box-filter an equirectangular map by an integer ``factor`` in both directions.

    Each output texel is the solid-angle-weighted mean of the ``factor x factor`` input texels
    it covers (texel solid angle proportional to cos(theta_top) - cos(theta_bottom)), so the
    integral of radiance over every block's solid angle, hence the map's radiant power, is kept
    exactly. Units unchanged. ``factor`` must divide the height and the width.
    """
    arr = np.asarray(img, dtype=np.float64)
    if arr.ndim != 3:
        raise HdriError(f"cannot downsample an array of shape {arr.shape}")
    h, w, c = arr.shape
    if int(factor) != factor or factor < 1 or h % factor or w % factor:
        raise HdriError(f"downsample factor {factor} must be a positive integer dividing "
                        f"{h} x {w}")
    factor = int(factor)
    edges = np.cos(np.pi * np.arange(h + 1) / h)
    omega = (edges[:-1] - edges[1:]).reshape(h // factor, factor, 1, 1, 1)
    blocks = arr.reshape(h // factor, factor, w // factor, factor, c)
    weight = omega.sum(axis=1).reshape(h // factor, 1, 1) * factor
    out = (blocks * omega).sum(axis=(1, 3)) / weight
    return np.ascontiguousarray(out, dtype=np.float32)
