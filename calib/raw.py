"""Develop camera RAW captures to linear 16-bit ProPhoto RGB with rawpy (LibRaw).

Development follows the paper's real-environment process: linear ProPhoto output (LibRaw's
ProPhoto matrix uses Bradford adaptation, matching :mod:`grassd.calib.colour_spaces`), gamma
(1, 1), no auto-brightening, and ``adjust_maximum_thr=0`` (LibRaw's default 0.75 would rescale
the data by a per-image maximum), with the camera's white balance or given multipliers.
LibRaw demosaics and white-balances in the camera's space (16 bits, clipped at full scale as
it always is); the matrix to ProPhoto (``sRGB -> ProPhoto @ rgb_cam``, what LibRaw's ProPhoto
output applies) is applied here in floating point, so a pixel keeps a negative component
instead of having it cut at 0: LibRaw's 16-bit ProPhoto output cuts each pixel's negatives,
which biases the mean of a noisy, saturated region (docs/calib/colour_chain.md), and is the same
wherever nothing is cut.
Both ``rawpy.imread`` and ``postprocess`` are guarded: a truncated file usually opens fine and
fails only when its pixels are decoded.

A RAW file is not trusted to be what its header says (:func:`open_raw`): its size on disk is
checked before LibRaw opens it (:data:`MAX_RAW_FILE_BYTES`), and the sensor and image
dimensions LibRaw reads from the header are checked (:data:`MAX_RAW_PIXELS`) before any pixel
is unpacked or developed: a 1.5 kB DNG may declare 60000 x 40000 photosites, which LibRaw would
try to allocate (4.8 GB) and develop (14 GB).
"""

from __future__ import annotations

import os
import stat
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import rawpy
from numpy.typing import ArrayLike, NDArray

from grassd.calib.colour_spaces import M_REC709_TO_PROPHOTO
from grassd.calib.errors import RawReadError, RawSizeError
from grassd.calib.regions import extract_checker_patches, quad_mean

#: Full scale of LibRaw's 16-bit output.
FULL_SCALE: int = 65535
#: Most photosites (and developed pixels) a RAW file may declare: 4 x 8192 x 4096 = 134 M.
#: Every camera sensor sold fits (medium format: 102 to 150 Mpx is the largest); a half-size
#: development of the largest is 8192 x 4096 texels, the largest panorama grassd.sim takes.
#: Developed at full size it takes about 3.2 GB (16-bit and float32 RGB).
MAX_RAW_PIXELS: int = 4 * 8192 * 4096
#: Largest RAW file accepted, in bytes (1 GiB): an uncompressed 16-bit linear DNG (three
#: samples per pixel) of 134 M pixels is 805 MB with its previews; a THETA Z1 DNG is about 50 MB.
MAX_RAW_FILE_BYTES: int = 1 << 30


@dataclass(frozen=True, eq=False)
class DevelopedRaw:
    """A developed capture.

    Attributes:
        rgb: (H, W, 3) float32 ProPhoto linear RGB (1 = 16-bit full scale), components
            below 0 kept (a pixel's noise in a saturated colour) and above 1 where the matrix
            takes them there.
        white_balance: the 4 channel multipliers (R, G, B, G2) LibRaw applied.
        path: the RAW file.
    """

    rgb: NDArray[np.float32]
    white_balance: tuple[float, float, float, float]
    path: Path

    def quad_mean(self, corners: ArrayLike) -> NDArray[np.float64]:
        """Mean ProPhoto linear RGB (3,) inside a quadrilateral (see :mod:`regions`)."""
        return quad_mean(self.rgb, corners)

    def checker_patches(self, chart_corners: ArrayLike, fraction: float = 0.5) -> NDArray:
        """(24, 3) mean ProPhoto linear RGB of the checker patches, in reading order; a mean
        below 0 (a saturated patch's component, noise about 0) reads 0, as the colour
        corrections' forms take non-negative patches."""
        return np.clip(extract_checker_patches(self.rgb, chart_corners, fraction=fraction),
                       0.0, None)


def _why(exc: BaseException) -> str:
    arg = exc.args[0] if exc.args else exc
    text = arg.decode(errors="replace") if isinstance(arg, bytes) else str(arg)
    return f"{type(exc).__name__}: {text}"


def _wb_params(white_balance: str | Sequence[float]) -> dict:
    if isinstance(white_balance, str):
        if white_balance == "camera":
            return {"use_camera_wb": True, "use_auto_wb": False}
        raise RawReadError(
            f"white_balance must be 'camera' or 3/4 channel multipliers; got {white_balance!r}"
        )
    wb = [float(v) for v in white_balance]
    if len(wb) == 3:
        wb.append(wb[1])
    if len(wb) != 4 or not all(np.isfinite(wb)) or min(wb) <= 0:
        raise RawReadError(
            f"white_balance multipliers must be 3 or 4 positive numbers (R, G, B[, G2]); got {wb}"
        )
    return {"user_wb": wb, "use_camera_wb": False, "use_auto_wb": False}


def open_raw(path: str | Path, sensor: tuple[int, int] | None = None) -> rawpy.RawPy:
    """Open a RAW file with LibRaw once its declared size is known to be sane; the caller
    closes it (``with open_raw(p) as raw:``).

    Checked before LibRaw reads a byte: a regular file of at most :data:`MAX_RAW_FILE_BYTES`;
    then, from the header LibRaw parsed (no pixel is unpacked yet), at most
    :data:`MAX_RAW_PIXELS` photosites on the sensor and pixels in the image, and, when
    ``sensor`` (width, height in photosites) is given, exactly that sensor size.

    Raises:
        RawSizeError: the declared sensor or image is beyond the limit, or not ``sensor``; the
            message names the size found and the limit (or the size expected).
        RawReadError: missing, not a regular file, too large on disk, or not a RAW file LibRaw
            can open.
    """
    p = Path(path)
    try:
        st = os.stat(p)
    except OSError as exc:
        raise RawReadError(f"RAW file {p} does not exist or cannot be read "
                           f"({exc.strerror or exc}); check the path") from None
    if not stat.S_ISREG(st.st_mode):
        raise RawReadError(f"RAW file {p} is not a regular file; give the camera's file itself")
    if st.st_size > MAX_RAW_FILE_BYTES:
        raise RawReadError(f"RAW file {p} is {st.st_size} bytes, more than the limit of "
                           f"{MAX_RAW_FILE_BYTES} bytes ({MAX_RAW_FILE_BYTES >> 20} MiB); "
                           "not a camera RAW grassd develops")
    try:
        raw = rawpy.imread(str(p))
    except (rawpy.LibRawError, OSError, ValueError, MemoryError) as exc:
        raise RawReadError(
            f"{p} is not a RAW file LibRaw can open ({_why(exc)}); "
            "give an unmodified camera RAW or DNG"
        ) from exc
    try:
        sizes = raw.sizes
        for what, w, h in (("sensor", sizes.raw_width, sizes.raw_height),
                           ("image", sizes.width, sizes.height)):
            if w <= 0 or h <= 0 or w * h > MAX_RAW_PIXELS:
                raise RawSizeError(
                    f"{p} declares a {what} of {w} x {h} = {w * h} pixels, outside 1 to "
                    f"{MAX_RAW_PIXELS} (the limit); nothing was decoded: the file is corrupt or "
                    "not a camera's RAW", what=what, width=w, height=h)
        if sensor is not None and (sizes.raw_width, sizes.raw_height) != tuple(sensor):
            w, h = sizes.raw_width, sizes.raw_height
            raise RawSizeError(
                f"{p} declares a sensor of {w} x {h} photosites, not the {sensor[0]} x "
                f"{sensor[1]} expected (the set-up shot's); nothing was decoded: a shot from "
                "another camera or mode, or a corrupt file", what="sensor", width=w, height=h)
    except BaseException:
        raw.close()
        raise
    return raw


def raw_sensor(path: str | Path) -> tuple[int, int]:
    """(width, height) in photosites of a RAW file's sensor, from its header alone
    (:func:`open_raw`'s checks; nothing is unpacked)."""
    with open_raw(path) as raw:
        return int(raw.sizes.raw_width), int(raw.sizes.raw_height)


def develop_raw(path: str | Path, white_balance: str | Sequence[float] = "camera",
                half_size: bool = False, sensor: tuple[int, int] | None = None) -> DevelopedRaw:
    """Develop a RAW file to linear ProPhoto RGB (16-bit precision, returned as float32 0..1).

    Args:
        path: a RAW file LibRaw understands (DNG, CR2, NEF, ARW, ...).
        white_balance: "camera" (as shot) or channel multipliers (R, G, B[, G2]).
        half_size: one pixel per 2 x 2 Bayer block (no demosaicing; half the width and height).
        sensor: the sensor size (width, height in photosites) the file must declare; None: any
            within :data:`MAX_RAW_PIXELS`.

    Raises:
        RawSizeError: a declared size beyond the limit or other than ``sensor`` (nothing
            decoded).
        RawReadError: missing, unreadable, truncated, corrupt or non-RAW file.
    """
    p = Path(path)
    params = _wb_params(white_balance)
    raw = open_raw(p, sensor)
    try:
        with raw:
            cam16 = raw.postprocess(
                output_color=rawpy.ColorSpace.raw,
                gamma=(1, 1),
                no_auto_bright=True,
                output_bps=16,
                adjust_maximum_thr=0.0,
                half_size=half_size,
                **params,
            )
            used = params.get("user_wb") or list(raw.camera_whitebalance)
            to_prophoto = (M_REC709_TO_PROPHOTO @ np.asarray(raw.color_matrix, np.float64)[:, :3]
                           ).astype(np.float32)
    except (rawpy.LibRawError, OSError, ValueError, MemoryError) as exc:
        raise RawReadError(
            f"{p} opened but its image data cannot be decoded ({_why(exc)}); "
            "the file is probably truncated or corrupt: copy it again from the camera"
        ) from exc
    if cam16.ndim != 3 or cam16.shape[2] != 3:
        raise RawReadError(f"{p} developed to shape {cam16.shape}, not an RGB image")
    rgb = (cam16.astype(np.float32) / np.float32(FULL_SCALE)) @ to_prophoto.T
    wb = tuple(float(v) for v in (list(used) + [0.0] * 4)[:4])
    return DevelopedRaw(rgb=rgb, white_balance=wb, path=p)  # type: ignore[arg-type]
