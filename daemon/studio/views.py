"""The studio's views, computed from a simulated characteristic with numpy: the table with its
R^2, the contrast a content designer has left, the pixel's image as a PNG, and the whole display
showing a picture through the table, drawn from the eye.

Colours shown are the simulation's, normalised as a camera with a fixed white balance sees
them (:mod:`grassd.daemon.core.calibration.simulation`: a white card at the display reads 1), then
encoded as sRGB (IEC 61966-2-1) for the screen.
"""

from __future__ import annotations

import base64
import io
import math
from typing import TYPE_CHECKING

import numpy as np

from grassd.daemon.content.colour_map import DisplayColours, levels_for_picture
from grassd.daemon.studio.inputs import StudioInputError
from grassd.daemon.studio.messages import ContrastView, TableView

if TYPE_CHECKING:
    from grassd.calib.characteristic import FittedCharacteristic

#: Just-noticeable colour difference (CIEDE2000) the contrast view counts steps against: about
#: 1 dE00 is perceptible to a trained observer side by side (Mokrzycki & Tatol 2011, "Colour
#: difference Delta E - a survey", Machine Graphics & Vision 20(4)).
JND_DE00: float = 1.0
#: The contrast view warns where a place in the audience keeps less than this fraction of the
#: OGCD range the eye has.
CONTRAST_LOSS: float = 0.3
#: Levels of an 8-bit table.
LEVELS: int = 256
#: Largest picture upload (bytes) and the largest side it is read at (pixels).
MAX_IMAGE_BYTES: int = 8 * 2**20
MAX_IMAGE_SIDE: int = 8192
#: Most pixels a picture is decoded at (4096 x 4096): it becomes one colour per display pixel,
#: so more adds nothing; decoded, it takes at most 64 MiB (4 bytes a pixel) and as much again
#: converted to RGB. A baseline JPEG is decoded at a reduced scale (1/2 to 1/8, still at least
#: the display's size) before this is checked, so a camera's photo of any side up to
#: :data:`MAX_IMAGE_SIDE` is taken; a progressive one is checked at its full size (its decoder
#: holds every DCT coefficient of the full size, 2 bytes a sample, whatever the scale), then
#: decoded at the reduced scale too, as the daemon's content decodes it.
MAX_IMAGE_PIXELS: int = 4096 * 4096


class PictureTooLarge(StudioInputError, ValueError):
    """An uploaded picture's header declares more pixels than the studio decodes
    (``width`` x ``height`` against ``limit``, a side or a pixel count); nothing was
    decoded."""

    def __init__(self, message: str, *, width: int, height: int, limit: int) -> None:
        super().__init__(message)
        self.width, self.height, self.limit = width, height, limit



def srgb_encode(linear: np.ndarray) -> np.ndarray:
    """IEC 61966-2-1 encoding of linear values (clipped to 0..1) as uint8
    (:func:`grassd.calib.colour_spaces.srgb_encode`)."""
    from grassd.calib.colour_spaces import srgb_encode as encode

    return np.rint(encode(linear) * 255.0).astype(np.uint8)


def png_data_url(rgb8: np.ndarray) -> str:
    """A ``data:image/png;base64,...`` URL of an (H, W, 3) uint8 image."""
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(rgb8), "RGB").save(buf, "PNG", compress_level=1)
    return "data:image/png;base64," + base64.b64encode(buf.getvalue()).decode("ascii")


def pixel_png(radiance: np.ndarray, white: np.ndarray) -> str:
    """The pixel view: linear Rec.709 radiance (H, W, 3) [nits] divided by the white card's
    ``white`` (3,) [nits], sRGB-encoded, as a PNG data URL."""
    return png_data_url(srgb_encode(np.asarray(radiance) / np.asarray(white)[None, None, :]))


def lab_to_srgb8(lab: np.ndarray) -> np.ndarray:
    """D50 CIELAB (..., 3) to sRGB uint8 (:func:`grassd.calib.colour_spaces.lab_to_srgb`)."""
    from grassd.calib.colour_spaces import lab_to_srgb

    return np.rint(lab_to_srgb(lab) * 255.0).astype(np.uint8)


def table_view(fit: FittedCharacteristic, active_um: np.ndarray | None) -> TableView:
    """The 8-bit table of a fitted characteristic and its R^2 (OGCD vs level) before (length
    linear in level) and after: the live table built from ``fit``
    (:func:`grassd.calib.length_table.build_length_table`), or ``active_um`` (256,) [um], the
    daemon's table, judged against ``fit``."""
    from grassd.calib.length_table import build_length_table, r_squared

    live = build_length_table(fit)
    levels = np.arange(LEVELS, dtype=np.float64)
    if active_um is None:
        lengths = live.lengths_mm
        achieved = live.achieved_ogcd
        r2_after = live.r2_after
    else:
        lengths = np.asarray(active_um, np.float64) / 1000.0
        achieved = fit(np.clip(lengths, fit.min_length_mm, fit.max_length_mm))
        r2_after = r_squared(levels, achieved)
    target = live.target_ogcd
    return {"source": "live" if active_um is None else "active",
            "lengths_mm": np.round(lengths, 4).tolist(),
            "achieved_ogcd": np.round(achieved, 4).tolist(),
            "uncalibrated_ogcd": np.round(live.uncalibrated_ogcd, 4).tolist(),
            "r2_before": live.r2_before, "r2_after": r2_after,
            "max_level_error": float(np.abs(achieved - target).max())}


def contrast_view(ogcd_range: float, jnd: float = JND_DE00) -> ContrastView:
    """What a content designer has to work with from one eye: the OGCD range (CIEDE2000), the
    colour step between adjacent levels of a linear table (range / 255), the smallest step in
    levels a viewer notices (``jnd`` dE00) and how many levels stay mutually distinguishable
    (range / jnd + 1, at most 256)."""
    step = ogcd_range / (LEVELS - 1)
    distinct = int(min(LEVELS, math.floor(ogcd_range / jnd) + 1)) if ogcd_range > 0 else 1
    min_step = int(math.ceil(jnd / step)) if step > 0 else LEVELS
    return {"ogcd_range": ogcd_range, "jnd_de00": jnd, "step_de00": step,
            "distinct_levels": distinct, "min_visible_step_levels": min(min_step, LEVELS)}


def audience_warning(ranges: np.ndarray, eye_range: float,
                     loss: float = CONTRAST_LOSS) -> np.ndarray:
    """True where a place keeps less than ``1 - loss`` of the eye's OGCD range."""
    return np.asarray(ranges) < (1.0 - loss) * eye_range


def picture_levels(data: bytes, rows: int, cols: int, colours: DisplayColours | None = None,
                   mode: str = "nearest_de00", normalise: str = "none") -> np.ndarray:
    """An uploaded picture (PNG, JPEG, ...) as the (rows, cols) 8-bit levels a grass display
    shows: its colours (:func:`picture_rgb`, which checks its size) mapped as the daemon's
    content is (:func:`grassd.daemon.content.colour_map.levels_for_picture` by ``mode`` and
    ``normalise``: the level whose predicted ``colours`` are nearest in CIEDE2000; without
    ``colours`` its luminance, ITU-R BT.601 weights as Pillow's "L")."""
    return levels_for_picture(picture_rgb(data, rows, cols), mode, colours, normalise)


def picture_rgb(data: bytes, rows: int, cols: int) -> np.ndarray:
    """An uploaded picture (PNG, JPEG, ...) as (rows, cols, 3) uint8 sRGB, box-filtered to one
    colour per display pixel (row 0 the picture's top). The size is checked from the header,
    before a pixel is decoded: :class:`PictureTooLarge` for a side over
    :data:`MAX_IMAGE_SIDE` or, at the scale it would be decoded at (a baseline JPEG's reduced
    by its decoder to no less than ``cols`` x ``rows``), more than :data:`MAX_IMAGE_PIXELS`
    pixels. ValueError with the reason for bytes that are not a readable picture."""
    from PIL import Image, UnidentifiedImageError

    if not data:
        raise ValueError("the body is empty: send the picture's PNG or JPEG bytes as the "
                         "request's body")
    if len(data) > MAX_IMAGE_BYTES:
        raise ValueError(f"the picture is {len(data) / 2**20:.1f} MiB; at most "
                         f"{MAX_IMAGE_BYTES // 2**20} MiB")
    try:
        with Image.open(io.BytesIO(data)) as im:  # reads the header only
            width, height = im.size
            if max(width, height) > MAX_IMAGE_SIDE:
                raise PictureTooLarge(
                    f"the picture is {width} x {height} pixels; at most {MAX_IMAGE_SIDE} on a "
                    "side (nothing was decoded): scale it down", width=width, height=height,
                    limit=MAX_IMAGE_SIDE)
            w, h = im.size  # a progressive JPEG's decoder holds every coefficient of this size
            im.draft(None, (cols, rows))  # JPEG: decode at 1/2..1/8 scale; others: no-op
            if not im.info.get("progressive"):
                w, h = im.size
            if w * h > MAX_IMAGE_PIXELS:
                raise PictureTooLarge(
                    f"the picture is {width} x {height} = {width * height} pixels; at most "
                    f"{MAX_IMAGE_PIXELS} ({math.isqrt(MAX_IMAGE_PIXELS)} x "
                    f"{math.isqrt(MAX_IMAGE_PIXELS)}) are decoded (nothing was): scale it down "
                    f"(the display shows {cols} x {rows}) or send a baseline JPEG", width=width,
                    height=height, limit=MAX_IMAGE_PIXELS)
            im.load()
            rgb = (im if im.mode == "RGB" else im.convert("RGB")).resize(
                (cols, rows), Image.Resampling.BOX)
    except UnidentifiedImageError:
        raise ValueError("not a picture Pillow can read (PNG, JPEG, ...): send the file's own "
                         "bytes as the request's body") from None
    except (OSError, Image.DecompressionBombError) as exc:  # a known format, broken or huge
        raise ValueError(f"not a picture Pillow can read: {exc}") from None
    return np.asarray(rgb, np.uint8)


def display_view(levels: np.ndarray, table_mm: np.ndarray, lengths_mm: np.ndarray,
                 lab: np.ndarray, pitch_mm: float, eye_m: np.ndarray,
                 width: int = 480) -> str:
    """The display showing ``levels`` (rows, cols; row 0 the picture's top) through
    ``table_mm`` (256,), drawn from the eye at ``eye_m`` (3,) [m, display centre at the
    origin, the audience towards -y] with a pinhole
    camera aimed at the display's centre: each pixel's square filled with the colour the
    simulation gives at its length (``lab`` (n, 3) D50 CIELAB at ``lengths_mm``, linearly
    interpolated; every pixel takes the simulated pixel's view). The picture stands upright
    for the audience: its top row on the display's far edge (+y). A PNG data URL."""
    from PIL import Image, ImageDraw

    levels = np.asarray(levels)[::-1]  # display row 0 is nearest the audience (-y)
    rows, cols = levels.shape
    length = np.asarray(table_mm, np.float64)[levels]  # (rows, cols) mm
    order = np.argsort(lengths_mm)
    xs = np.asarray(lengths_mm, np.float64)[order]
    colour = np.stack([np.interp(length, xs, np.asarray(lab)[order, k]) for k in range(3)],
                      axis=-1)
    rgb = lab_to_srgb8(colour)
    p = pitch_mm / 1000.0
    r, c = np.meshgrid(np.arange(rows), np.arange(cols), indexing="ij")
    cx = (c - (cols - 1) / 2) * p
    cy = (r - (rows - 1) / 2) * p
    half = p / 2
    corners = np.stack([np.stack([cx + sx * half, cy + sy * half, np.zeros_like(cx)], -1)
                        for sx, sy in ((-1, -1), (1, -1), (1, 1), (-1, 1))], axis=2)
    eye = np.asarray(eye_m, np.float64)
    forward = -eye / np.linalg.norm(eye)
    right = np.cross(forward, [0.0, 0.0, 1.0])
    if np.linalg.norm(right) < 1e-9:  # straight above: rows run up the picture
        right = np.array([1.0, 0.0, 0.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    rel = corners - eye
    depth = rel @ forward
    u = (rel @ right) / depth
    v = (rel @ up) / depth
    urange = max(float(np.ptp(u)), 1e-9)
    vrange = max(float(np.ptp(v)), 1e-9)
    height = int(round(width * min(1.0, max(0.25, vrange / urange))))
    scale = 0.92 * min(width / urange, height / vrange)
    px = (u - (u.max() + u.min()) / 2) * scale + width / 2
    py = height / 2 - (v - (v.max() + v.min()) / 2) * scale
    img = Image.new("RGB", (width, height), (24, 24, 24))
    draw = ImageDraw.Draw(img)
    # far pixels first, so nearer ones cover them
    for idx in np.argsort(-depth.mean(axis=2), axis=None):
        i, j = divmod(int(idx), cols)
        draw.polygon([(float(px[i, j, k]), float(py[i, j, k])) for k in range(4)],
                     fill=tuple(int(x) for x in rgb[i, j]))
    return png_data_url(np.asarray(img))
