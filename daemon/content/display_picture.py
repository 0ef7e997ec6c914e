"""The status page's picture of what the display shows, as its controllers report it.

:func:`shown_png` draws a :class:`~grassd.daemon.content.shown.ShownDisplay` as a PNG, one
``scale`` x ``scale`` block per pixel, row 0 at the top and column 0 on the left: each pixel in
the colour the active table's calibration predicts for its grass length (from the reference
viewpoint) when the content has those colours, else on a green scale from dark (no grass) to
bright green (``max_length_um``); a pixel whose controller did not answer is grey.
:func:`shown_figure` embeds it in the page (a data URI) with its caption: when it was read,
from how many controllers, and which did not answer.
"""

from __future__ import annotations

import base64
import html
import io
from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

from grassd.daemon.content.shown import ShownDisplay
from grassd.daemon.core.safe_text import one_line

#: grey of a pixel whose controller did not answer (sRGB 8-bit)
MISSING_RGB8 = (128, 128, 128)
#: the green scale's ends, no grass and the longest grass (sRGB 8-bit)
SHORT_RGB8 = (20, 36, 16)
LONG_RGB8 = (60, 200, 40)
#: the picture's width is about this many image pixels (each display pixel a square block)
PICTURE_WIDTH_PX = 256


def shown_rgb8(shown: ShownDisplay) -> NDArray[np.uint8]:
    """(rows, cols, 3) sRGB 8-bit colours of the display's pixels (see module docstring)."""
    from grassd.calib.colour_spaces import lab_to_srgb

    length = shown.lengths_um
    known = np.isfinite(length)
    safe = np.where(known, length, 0.0)
    if shown.colours is not None:
        rgb = lab_to_srgb(shown.colours.at(safe)) * 255.0
    else:
        f = np.clip(safe / max(shown.max_length_um, 1), 0.0, 1.0)[..., None]
        rgb = (1.0 - f) * np.asarray(SHORT_RGB8, float) + f * np.asarray(LONG_RGB8, float)
    rgb = np.where(known[..., None], rgb, np.asarray(MISSING_RGB8, float))
    return np.rint(np.clip(rgb, 0.0, 255.0)).astype(np.uint8)


def picture_scale(shown: ShownDisplay) -> int:
    """Image pixels per display pixel (at least 1) for a picture about
    :data:`PICTURE_WIDTH_PX` wide."""
    return max(1, PICTURE_WIDTH_PX // max(shown.cols, 1))


def shown_png(shown: ShownDisplay, scale: int | None = None) -> bytes:
    """The picture as PNG bytes: (rows * scale) x (cols * scale) image pixels, ``scale``
    default :func:`picture_scale`."""
    from PIL import Image

    s = picture_scale(shown) if scale is None else scale
    img = np.repeat(np.repeat(shown_rgb8(shown), s, axis=0), s, axis=1)
    buf = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(img), "RGB").save(buf, "PNG")
    return buf.getvalue()


def shown_caption(shown: ShownDisplay, clock: Callable[[float], str]) -> str:
    """The caption (plain text): when it was read (``clock``: epoch s -> local time), from how
    many controllers, which did not answer."""
    total = len(shown.answered) + len(shown.missing)
    scale = "predicted colours" if shown.colours is not None else \
        f"green: 0 to {shown.max_length_um / 1000:g} mm"
    text = (f"as the controllers report it, read {clock(shown.read_at)} from "
            f"{len(shown.answered)} of {total} controller(s); {scale}")
    if shown.missing:
        text += "; grey: no answer from " + ", ".join(
            f"{one_line(m.name)} ({one_line(m.error)})" for m in shown.missing)
    return text


def shown_figure(shown: ShownDisplay | None, clock: Callable[[float], str]) -> str:
    """The page's figure (HTML) of ``shown``; empty when there is none."""
    if shown is None:
        return ""
    uri = base64.b64encode(shown_png(shown)).decode("ascii")
    caption = html.escape(one_line(shown_caption(shown, clock), max_chars=None))
    return (f'<figure class="shown"><img src="data:image/png;base64,{uri}" '
            f'alt="the display now ({shown.rows} x {shown.cols} pixels)">'
            f"<figcaption>{caption}</figcaption></figure>")
