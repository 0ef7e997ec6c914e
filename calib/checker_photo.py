"""The colour checker's photo: its white balance from the undeveloped sensor data, and the
analytic virtual checker that the simulation is compared with.

A site's photos (``grassd validate`` and ``grassd fit`` of a pixel, ``grassd measure`` of the
display) are developed with the LibRaw channel multipliers that make the checker's grey patch
its reference colour (:func:`checker_white_balance`), and scaled so that grey has Y = 0.18; the
simulation, normalised to a white card, is scaled the same way (:func:`virtual_checker`).
:func:`checker_scene` is the radiance a virtual camera photographs of a checker lying at the
display (``grassd experiment virtual-capture``, the simulated display of ``grassd measure``).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from grassd.calib.charts import CHART_GRID, ReferenceChart
from grassd.calib.colour_spaces import luminance, prophoto_to_rec709
from grassd.calib.errors import CheckerPhotoError, CornersOutsideImageError
from grassd.calib.exposure import GREY_CARD_Y
from grassd.calib.raw import open_raw
from grassd.calib.regions import (
    apply_homography,
    checker_patch_quads,
    homography,
    quad_mask,
    quad_max,
)


def check_inside(corners: Sequence[Sequence[float]], shape: tuple[int, ...], path: Path,
                 what: str) -> None:
    """Raise :class:`CornersOutsideImageError` unless every (x, y) of ``corners`` (pixels) lies
    within an image of ``shape`` (rows, columns, ...), the photo ``path``; ``what`` names the
    corners in the message (\"checker\", \"pixel quad\")."""
    c = np.asarray(corners, dtype=np.float64)
    h, w = shape[:2]
    bad = (c[:, 0] < 0) | (c[:, 0] > w) | (c[:, 1] < 0) | (c[:, 1] > h)
    if bad.any():
        raise CornersOutsideImageError(
            f"{what} corner(s) {c[bad].tolist()} lie outside {path.name} ({w} x {h} pixels; "
            "x = column 0..width, y = row 0..height); check the corner coordinates")


def developed_to_raw(corners: Sequence[Sequence[float]], raw_shape: tuple[int, ...],
                     flip: int) -> NDArray[np.float64]:
    """Map (x, y) points of the developed image onto the undeveloped sensor data.

    LibRaw's ``flip`` (from the camera's orientation tag): 0 none, 3 rotated 180 deg, 5 rotated
    90 deg counter-clockwise, 6 rotated 90 deg clockwise; ``raw_shape`` = (rows, columns) of
    the visible sensor area.

    >>> developed_to_raw([[1.0, 2.0]], (10, 20), 3).tolist()
    [[19.0, 8.0]]
    """
    c = np.asarray(corners, dtype=np.float64).reshape(-1, 2)
    h, w = raw_shape[:2]
    x, y = c[:, 0], c[:, 1]
    if flip == 0:
        return c
    if flip == 3:
        return np.column_stack([w - x, h - y])
    if flip == 6:  # developed = raw turned clockwise: (xd, yd) = (h - yr, xr)
        return np.column_stack([y, h - x])
    if flip == 5:  # counter-clockwise: (xd, yd) = (yr, w - xr)
        return np.column_stack([w - y, x])
    raise CheckerPhotoError(f"unsupported image orientation (LibRaw flip {flip}); rotate or "
                            "mirror the RAW back to its sensor orientation")


def checker_white_balance(path: Path, corners: Sequence[Sequence[float]],
                          chart: ReferenceChart) -> tuple[float, float, float, float]:
    """LibRaw channel multipliers (R, G, B, G2) that develop the checker's grey patch to the
    chromaticity of its reference colour (a grey card is nearly, not exactly, neutral).

    Measured on the undeveloped Bayer data: ``c`` = the black-subtracted mean of each colour
    filter inside the grey patch. LibRaw develops ``out = rgb_cam . diag(wb) . c`` (then a fixed
    sRGB -> ProPhoto matrix), so ``wb = (rgb_cam^-1 . t) / c`` with ``t`` the reference grey in
    linear sRGB; normalised to green = 1. Where LibRaw reports no colour matrix the grey is
    made neutral (``wb = mean green / c``).
    """
    with open_raw(path) as raw:
        img = raw.raw_image_visible.astype(np.float64)
        colours = np.asarray(raw.raw_colors_visible)
        black = np.asarray(raw.black_level_per_channel, dtype=np.float64)
        white = float(raw.white_level)
        desc = raw.color_desc.decode(errors="replace")
        rgb_cam = np.asarray(raw.color_matrix, dtype=np.float64)[:, :3]
        flip = int(raw.sizes.flip)
    developed_shape = img.shape[::-1] if flip in (5, 6) else img.shape
    check_inside(corners, developed_shape, path, "checker")
    corners = developed_to_raw(corners, img.shape, flip)
    if len(desc) not in (3, 4) or set(desc[:3]) != set("RGB") or set(desc) - set("RGB"):
        raise CheckerPhotoError(f"{path.name}: colour filters {desc!r} are not an R/G/B Bayer "
                                "sensor; white balance from the checker needs one")
    quads = checker_patch_quads(corners)
    # Any clipped patch, not only the grey, would bend the colour correction fitted to the
    # patches: a metered shot of a checker on a dark ground clips its white and light patches
    # (the grey not), and its 3x3 correction was then 3.2 dE00 off on average, 7.2 at most.
    clipped = [i for i, q in enumerate(quads) if quad_max(img, q) >= white]
    if clipped:
        names = ", ".join(f"{i + 1} ({chart.patch_names[i]})" for i in clipped)
        raise CheckerPhotoError(f"{path.name}: the checker's patch(es) {names} are clipped (raw "
                                f"values at the white level {white:g}); lower the exposure")
    mask = quad_mask(img.shape, quads[chart.grey_index()])
    means = np.zeros(len(desc))
    for c in range(len(desc)):
        sel = mask & (colours == c)
        if not sel.any():
            raise CheckerPhotoError(f"{path.name}: the grey patch covers no {desc[c]} "
                                    "photosite; the checker is too small in the photo")
        means[c] = img[sel].mean() - black[c]
    if means.min() <= 0:
        raise CheckerPhotoError(f"{path.name}: the checker's grey patch reads no light above black "
                                f"({means.round(1).tolist()}); check the checker corners")
    index = {ch: [c for c in range(len(desc)) if desc[c] == ch] for ch in "RGB"}
    target = np.ones(3)
    if np.isfinite(rgb_cam).all() and abs(np.linalg.det(rgb_cam)) > 1e-9:
        grey_srgb = prophoto_to_rec709(chart.prophoto()[chart.grey_index()])
        target = np.linalg.solve(rgb_cam, grey_srgb)
        if (target <= 0).any():
            target = np.ones(3)
    per = {ch: target["RGB".index(ch)] for ch in "RGB"}
    mult = np.array([per[desc[c]] / means[c] for c in range(len(desc))])
    mult = mult / np.mean([mult[c] for c in index["G"]])
    wb = [float(v) for v in mult] + ([float(mult[index["G"][0]])] if len(desc) == 3 else [])
    return tuple(wb)  # type: ignore[return-value]


def virtual_checker(chart: ReferenceChart) -> tuple[NDArray[np.float64], float]:
    """Normalised ProPhoto linear patches (24, 3) of the analytic virtual checker and the factor
    ``s`` (0.18 / Y of its grey) that the white-card-normalised simulation is scaled by."""
    pp = chart.prophoto()  # the analytic patches need no Rec.709 detour (nor its gamut)
    s = GREY_CARD_Y / float(luminance(pp[chart.grey_index()], "prophoto"))
    return pp * s, s


# ------------------------------------------------------------------ a simulated checker photo
#: Where the chart's patch area lies in the checker photo, as fractions of (width, height):
#: top-left, top-right, bottom-right, bottom-left (slightly in perspective).
CHART_LAYOUT: NDArray[np.float64] = np.array(
    [(0.12, 0.14), (0.90, 0.18), (0.86, 0.88), (0.09, 0.82)])
#: Albedo of the chart body between the patches (linear).
CHART_BODY_ALBEDO: float = 0.03


def checker_scene(chart: ReferenceChart, white_rgb709: Sequence[float], width: int = 384,
                  height: int = 256) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Radiance image (height, width, 3) of a colour checker lying flat at the display, and the
    (4, 2) image corners of its patch area (TL, TR, BR, BL; pixels (x, y)).

    A Lambertian patch of albedo ``a`` under horizontal irradiance ``E`` has radiance
    ``a * E / pi`` = ``a * white_rgb709`` (linear Rec.709, negative components kept for the
    patches outside its gamut, as scRGB does); patches fill 80 % of their cells.
    """
    corners = CHART_LAYOUT * np.array([width, height])
    albedo = prophoto_to_rec709(chart.prophoto())  # scRGB: out-of-gamut patches go negative
    hinv = homography(corners, [(0, 0), (1, 0), (1, 1), (0, 1)])
    yy, xx = np.mgrid[0:height, 0:width]
    uv = apply_homography(hinv, np.stack([xx + 0.5, yy + 0.5], axis=-1))
    rows, cols = CHART_GRID
    u, v = uv[..., 0], uv[..., 1]
    col = np.floor(u * cols).astype(int)
    row = np.floor(v * rows).astype(int)
    inside = ((u >= 0) & (u < 1) & (v >= 0) & (v < 1)
              & (np.abs(u * cols - col - 0.5) < 0.4) & (np.abs(v * rows - row - 0.5) < 0.4))
    img = np.full((height, width, 3), CHART_BODY_ALBEDO)
    idx = np.clip(row, 0, rows - 1) * cols + np.clip(col, 0, cols - 1)
    img[inside] = albedo[idx[inside]]
    return img * np.asarray(white_rgb709, dtype=np.float64), corners
