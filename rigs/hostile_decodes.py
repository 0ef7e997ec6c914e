"""Hostile files that are small on disk and huge decoded, and what decoding one
costs a fresh process: a flat PNG of any size written row by row, a DNG whose header declares
another size than its data, and :func:`run_child`, which runs a decode in a new Python and
returns what it did with its peak resident memory. The EXR and Radiance builders are in
:mod:`grassd.rigs.inbox_fuzz` (:func:`~grassd.rigs.inbox_fuzz.write_flat_exr`)."""

from __future__ import annotations

import json
import struct
import subprocess
import sys
import textwrap
import zlib
from pathlib import Path

import numpy as np


def flat_png(width: int, height: int) -> bytes:
    """An 8-bit RGB PNG of ``width`` x ``height`` black pixels, compressed row by row (never
    held whole: 8192 x 8192 is 191 KiB)."""
    def chunk(kind: bytes, body: bytes) -> bytes:
        return (len(body).to_bytes(4, "big") + kind + body
                + zlib.crc32(kind + body).to_bytes(4, "big"))

    z = zlib.compressobj(9)
    row = bytes(1 + 3 * width)  # filter 0, then the row
    idat = b"".join(z.compress(row) for _ in range(height)) + z.flush()
    ihdr = width.to_bytes(4, "big") + height.to_bytes(4, "big") + bytes([8, 2, 0, 0, 0])
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", idat)
            + chunk(b"IEND", b""))


def small_dng(path: Path, width: int = 128, height: int = 64) -> Path:
    """A real DNG of ``width`` x ``height`` photosites (a flat grey, :mod:`grassd.calib.dng`)."""
    from grassd.calib.dng import DngCamera, mosaic, write_dng

    cam = DngCamera()
    write_dng(path, mosaic(np.full((height, width, 3), 0.3), cam), cam)
    return path


def dng_declaring(src: Path, dest: Path, width: int, height: int) -> int:
    """Copy DNG ``src`` to ``dest`` with ImageWidth / ImageLength patched to ``width`` x
    ``height`` (the pixel data stays the small original); the file's size in bytes."""
    import tifffile

    data = bytearray(src.read_bytes())
    with tifffile.TiffFile(src) as tif:
        tags = {t.code: t for t in tif.pages[0].tags.values()}
    for code, value in ((256, width), (257, height)):
        fmt = "<H" if tags[code].dtype == 3 else "<I"
        struct.pack_into(fmt, data, tags[code].offset + 8, value)
    dest.write_bytes(bytes(data))
    return len(data)


_WRAPPER = """
import json, sys
out = {}
try:
%s
except Exception as exc:
    out.update(error=type(exc).__name__, message=str(exc))
for line in open("/proc/self/status"):
    if line.startswith("VmHWM:"):
        out["peak_mib"] = int(line.split()[1]) / 1024
print(json.dumps(out))
"""


def run_child(body: str, *args: str, timeout_s: float = 120.0) -> dict:
    """Run ``body`` (statements that may fill the dict ``out`` with JSON values; ``sys.argv[1:]``
    are ``args``) in a new Python: ``out``, plus ``error`` and ``message`` when it raised, plus
    ``peak_mib``, the process's peak resident memory (VmHWM, MiB). AssertionError when the
    process itself fails."""
    code = _WRAPPER % textwrap.indent(textwrap.dedent(body).strip(), "    ")
    done = subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True,
                          timeout=timeout_s)
    if done.returncode != 0:
        raise AssertionError(f"child failed ({done.returncode}): {done.stderr[-2000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])
