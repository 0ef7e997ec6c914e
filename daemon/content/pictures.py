"""Pictures and animations from files (PNG, JPEG, animated GIF and APNG, through Pillow),
resized to the display: one frame of ``rows`` x ``cols`` sRGB colours per picture frame,
with how long each is shown.

A file is read whole only when it is within ``max_bytes``; each frame is box-filtered to the
display's size (one value per grass pixel), so an animation costs rows x cols x 3 bytes per
frame; more than :data:`MAX_FRAMES` frames, a side over :data:`MAX_SIDE`, or more pixels to
decode than :data:`MAX_FRAME_PIXELS` a frame or :data:`MAX_TOTAL_PIXELS` in all is refused
from the header, before a pixel is decoded.
"""

from __future__ import annotations

import io
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from grassd.daemon.core.errors import DaemonError

#: the most frames an animation may have
MAX_FRAMES = 10_000
#: the longest side of a picture file (pixels)
MAX_SIDE = 16_384
#: the most pixels of one frame (a 4096 x 4096 picture), and of all frames together: what
#: decoding one file may cost
MAX_FRAME_PIXELS = 4096 * 4096
MAX_TOTAL_PIXELS = 1 << 30
#: a frame without a duration of its own (a still, or a GIF frame of 0 ms) stays this long [s]
DEFAULT_FRAME_S = 0.1


class PictureError(DaemonError):
    """A picture or animation file cannot be shown (missing, too large, not a picture)."""


@dataclass(frozen=True, eq=False)
class Animation:
    """``frames`` (n, rows, cols, 3) uint8 sRGB, row 0 the picture's top; ``durations_s``
    (n,) how long each frame stays [s]; ``name`` the file's name."""

    frames: NDArray[np.uint8]
    durations_s: NDArray[np.float64]
    name: str

    @property
    def length_s(self) -> float:
        """One pass through every frame [s]."""
        return float(self.durations_s.sum())

    def index_at(self, t_s: float) -> int:
        """The frame shown ``t_s`` seconds after the start, looping."""
        if len(self.durations_s) == 1:
            return 0
        ends = np.cumsum(self.durations_s)
        return int(np.searchsorted(ends, t_s % ends[-1], side="right")) % len(ends)


def decode_animation(data: bytes, rows: int, cols: int, name: str = "picture") -> Animation:
    """The frames of the picture file ``data`` resized to ``rows`` x ``cols``; raises
    :class:`PictureError` with the reason."""
    from PIL import Image, ImageSequence, UnidentifiedImageError

    try:
        with Image.open(io.BytesIO(data)) as im:
            if max(im.size) > MAX_SIDE:
                raise PictureError(f"{name}: {im.size[0]} x {im.size[1]} pixels; at most "
                                   f"{MAX_SIDE} on a side: scale it down")
            n = getattr(im, "n_frames", 1)
            if n > MAX_FRAMES:
                raise PictureError(f"{name}: {n} frames; at most {MAX_FRAMES}")
            px = im.size[0] * im.size[1]
            if px > MAX_FRAME_PIXELS or px * n > MAX_TOTAL_PIXELS:
                raise PictureError(f"{name}: {n} frame(s) of {im.size[0]} x {im.size[1]} "
                                   f"pixels; at most {MAX_FRAME_PIXELS} pixels a frame and "
                                   f"{MAX_TOTAL_PIXELS} in all: scale it down")
            im.draft("RGB", (cols, rows))  # a JPEG decodes at a reduced scale when it can
            frames, durations = [], []
            for frame in ImageSequence.Iterator(im):
                rgb = frame.convert("RGB").resize((cols, rows), Image.Resampling.BOX)
                frames.append(np.asarray(rgb, np.uint8))
                ms = frame.info.get("duration") or 0
                durations.append(float(ms) / 1000.0 if ms else DEFAULT_FRAME_S)
    except UnidentifiedImageError:
        raise PictureError(f"{name}: not a picture Pillow can read (PNG, JPEG, GIF, APNG)") \
            from None
    except (OSError, ValueError, Image.DecompressionBombError) as exc:
        raise PictureError(f"{name}: not a picture Pillow can read: {exc}") from None
    return Animation(np.stack(frames), np.asarray(durations), name)


def load_animation(path: Path, rows: int, cols: int, max_bytes: int) -> Animation:
    """The picture or animation file at ``path`` resized to ``rows`` x ``cols``, read only
    when it is at most ``max_bytes``; raises :class:`PictureError` with the reason."""
    try:
        size = path.stat().st_size
        if size > max_bytes:
            raise PictureError(f"{path}: {size / 2**20:.1f} MiB; at most "
                               f"{max_bytes / 2**20:.0f} MiB ([content] max_picture_mib)")
        data = path.read_bytes()
    except OSError as exc:
        raise PictureError(f"cannot read picture {path}: {exc.strerror}") from None
    return decode_animation(data, rows, cols, path.name)
