"""The colour checker's photo: its white balance from the undeveloped sensor data, and the
analytic virtual checker that the simulation is compared with.

A site's photos (``grassd validate`` and ``grassd fit`` of a pixel, ``grassd measure`` of the
display) are developed with the LibRaw channel multipliers that make the checker's grey patch
its reference colour (:func:`checker_white_balance`), and scaled so that grey has Y = 0.18; the
simulation, normalised to a white card, is scaled the same way (:func:`virtual_checker`).
:func:`checker_scene` is the radiance a virtual camera photographs of a checker lying at the
display (``grassd experiment virtual-capture``, the simulated display of ``grassd measure``).

Every path from a checker photo to a white balance or a colour correction refuses a photo whose
patches clip (:func:`checker_clipping`, :class:`~grassd.calib.errors.ClippedCheckerError`):
:func:`checker_white_balance` itself, and :func:`checker_photo_patches`, the developed patches
for a colour-correction fit. A clipped light patch (the grey unclipped) bent the 3x3 correction
of a measured set-up shot far from the truth, neutrals included; a channel clipped at black (a
sensor modelled with negative responses cut at 0) does the same to saturated patches. Clipping
is judged on the undeveloped sensor data, per colour filter, against the level at which the
*development* saturates that filter: LibRaw scales filter ``c`` by ``wb_c / min(wb)`` and clips
at full scale (its highlight mode 0), so a filter with a larger multiplier saturates in the
developed image before its raw values reach the white level.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from grassd.calib.charts import CHART_GRID, ReferenceChart
from grassd.calib.colour_spaces import luminance, prophoto_to_rec709
from grassd.calib.errors import CheckerPhotoError, ClippedCheckerError, CornersOutsideImageError
from grassd.calib.exposure import GREY_CARD_Y
from grassd.calib.raw import develop_raw, open_raw
from grassd.calib.regions import (
    apply_homography,
    checker_patch_quads,
    homography,
    quad_mask,
    quad_values,
)

#: A patch clips high in a colour filter when a photosite of that filter inside its sampled
#: area reaches this fraction of the range from black to the level at which the development
#: saturates the filter (a sensor's response already bends just below saturation).
HIGH_CLIP_FRACTION: float = 0.98
#: A patch clips low (reads no light) in a colour filter when at least this fraction of that
#: filter's photosites inside its sampled area read at or below the black level: about half do
#: for a zero signal under read noise, all of them without; 2 % do at a signal of two read-noise
#: standard deviations, which is dim but not clipped.
LOW_CLIP_FRACTION: float = 0.25


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


@dataclass(frozen=True, eq=False)
class _Sensor:
    """The undeveloped data of a RAW file LibRaw read (see :func:`_read_sensor`)."""

    img: NDArray[np.float64]
    colours: NDArray[np.integer]
    black: NDArray[np.float64]
    white: float
    desc: str
    rgb_cam: NDArray[np.float64]
    flip: int
    camera_wb: NDArray[np.float64]


def _read_sensor(path: Path) -> _Sensor:
    with open_raw(path) as raw:
        return _Sensor(img=raw.raw_image_visible.astype(np.float64),
                       colours=np.asarray(raw.raw_colors_visible),
                       black=np.asarray(raw.black_level_per_channel, dtype=np.float64),
                       white=float(raw.white_level),
                       desc=raw.color_desc.decode(errors="replace"),
                       rgb_cam=np.asarray(raw.color_matrix, dtype=np.float64)[:, :3],
                       flip=int(raw.sizes.flip),
                       camera_wb=np.asarray(raw.camera_whitebalance, dtype=np.float64))


def _raw_quads(sensor: _Sensor, corners: Sequence[Sequence[float]], path: Path) -> NDArray:
    """The checker's (24, 4, 2) patch sampling quads on the sensor data."""
    developed_shape = sensor.img.shape[::-1] if sensor.flip in (5, 6) else sensor.img.shape
    check_inside(corners, developed_shape, path, "checker")
    return checker_patch_quads(developed_to_raw(corners, sensor.img.shape, sensor.flip))


@dataclass(frozen=True)
class CheckerClipping:
    """Which of a checker photo's patches clip (0-based indices, reading order).

    Attributes:
        high: patches with a colour filter near the level where the development saturates it.
        low: patches with a colour filter reading no light (at the black level).
        high_filters, low_filters: for each patch of ``high`` / ``low``, the filters ("R", "G",
            "B") that clip, e.g. "RG".
    """

    high: tuple[int, ...]
    low: tuple[int, ...]
    high_filters: tuple[str, ...]
    low_filters: tuple[str, ...]

    @property
    def clipped(self) -> bool:
        """True when any patch clips."""
        return bool(self.high or self.low)


def _multipliers(sensor: _Sensor, white_balance: str | Sequence[float] | None) -> NDArray:
    n = len(sensor.desc)
    if white_balance is None:
        return np.ones(n)
    if isinstance(white_balance, str):
        if white_balance != "camera":
            raise CheckerPhotoError(f"white_balance must be 'camera', None or channel "
                                    f"multipliers (R, G, B[, G2]); got {white_balance!r}")
        wb = sensor.camera_wb
    else:
        wb = np.asarray([float(v) for v in white_balance], dtype=np.float64)
        if wb.size == 3:
            wb = np.append(wb, wb[1])
    if wb.size < n or not np.isfinite(wb[:n]).all() or (wb[:n] <= 0).any():
        return np.ones(n)  # LibRaw develops such a file without those multipliers
    return wb[:n]


def _clipping(sensor: _Sensor, quads: NDArray,
              white_balance: str | Sequence[float] | None) -> CheckerClipping:
    n = len(sensor.desc)
    mult = _multipliers(sensor, white_balance)
    black = sensor.black[:n] if sensor.black.size >= n else np.full(n, sensor.black.flat[0])
    saturates = black + (sensor.white - black) * mult.min() / mult  # per filter
    high_at = black + HIGH_CLIP_FRACTION * (saturates - black)
    names = [sensor.desc[c] for c in range(n)]
    high: dict[int, str] = {}
    low: dict[int, str] = {}
    for i, q in enumerate(quads):
        vals = quad_values(sensor.img, q)
        cols = quad_values(sensor.colours, q)
        if vals.size == 0:
            continue
        counts = np.bincount(cols, minlength=n)[:n]
        over = np.bincount(cols, weights=vals >= high_at[cols], minlength=n)[:n] > 0
        dark = np.bincount(cols, weights=vals <= black[cols], minlength=n)[:n]
        under = (counts > 0) & (dark >= LOW_CLIP_FRACTION * np.maximum(counts, 1))
        if over.any():
            high[i] = "".join(dict.fromkeys(names[c] for c in np.flatnonzero(over)))
        if under.any():
            low[i] = "".join(dict.fromkeys(names[c] for c in np.flatnonzero(under)))
    return CheckerClipping(tuple(high), tuple(low), tuple(high.values()), tuple(low.values()))


def _refuse(clip: CheckerClipping, chart: ReferenceChart, path: Path, sensor: _Sensor) -> None:
    if not clip.clipped:
        return

    def listed(idx: tuple[int, ...], filters: tuple[str, ...]) -> str:
        return ", ".join(f"{i + 1} ({chart.patch_names[i]}) in {f}"
                         for i, f in zip(idx, filters, strict=True))

    parts = []
    if clip.high:
        parts.append(f"the checker's patch(es) {listed(clip.high, clip.high_filters)} are "
                     f"clipped near the white level (raw values within "
                     f"{100 * (1 - HIGH_CLIP_FRACTION):g} % of where the development saturates "
                     f"the filter; white level {sensor.white:g})")
    if clip.low:
        parts.append(f"the checker's patch(es) {listed(clip.low, clip.low_filters)} are "
                     f"clipped at 0 (at least {100 * LOW_CLIP_FRACTION:g} % of the filter's "
                     f"photosites at the black level: no light read)")
    if clip.high and clip.low:
        fix = ("the checker's light and dark patches do not both fit the sensor's range: light "
               "the checker evenly, lower the exposure until the light patches stay below the "
               "white level, and use a sensor whose every filter responds to every patch")
    elif clip.high:
        fix = "lower the exposure (or the light) until the lightest patch stays below it"
    else:
        fix = ("raise the exposure as far as the light patches allow; a filter that reads "
               "nothing of a lit patch is a sensor with negative responses cut at 0, which no "
               "photodiode has: model the camera by non-negative spectral sensitivities")
    raise ClippedCheckerError(f"{path.name}: " + "; ".join(parts) + f"; {fix}",
                              high=clip.high, low=clip.low)


def raw_rgb_cam(path: Path) -> NDArray[np.float64]:
    """(3, 3) LibRaw's camera -> linear sRGB matrix (``rgb_cam``) of a RAW file, from its
    header's profile (e.g. a DNG's ColorMatrix1); what its development applies after the white
    balance (for :func:`grassd.calib.camera_response.camera_correction`)."""
    with open_raw(path) as raw:
        return np.asarray(raw.color_matrix, dtype=np.float64)[:, :3]


def checker_clipping(path: Path, corners: Sequence[Sequence[float]],
                     white_balance: str | Sequence[float] | None = "camera") -> CheckerClipping:
    """Which patches of the checker photo ``path`` clip (see the module docstring).

    Args:
        path: the checker's RAW file.
        corners: (4, 2) patch-area corners (x, y pixels of the developed image; TL, TR, BR, BL).
        white_balance: the multipliers the photo will be developed with: "camera" (as shot),
            (R, G, B[, G2]), or None to judge against the white level alone.
    """
    p = Path(path)
    sensor = _read_sensor(p)
    return _clipping(sensor, _raw_quads(sensor, corners, p), white_balance)


def refuse_clipped_checker(path: Path, corners: Sequence[Sequence[float]], chart: ReferenceChart,
                           white_balance: str | Sequence[float] | None = "camera") -> None:
    """Raise :class:`~grassd.calib.errors.ClippedCheckerError` (naming the patches, their
    filters and the fix) when any patch of the checker photo clips (:func:`checker_clipping`):
    near the white level, or at 0 (a real sensor's response is never negative, so a patch
    that reads nothing had too little light)."""
    p = Path(path)
    sensor = _read_sensor(p)
    _refuse(_clipping(sensor, _raw_quads(sensor, corners, p), white_balance), chart, p, sensor)


def checker_photo_patches(path: Path, corners: Sequence[Sequence[float]], chart: ReferenceChart,
                          white_balance: str | Sequence[float] = "camera"
                          ) -> NDArray[np.float64]:
    """(24, 3) mean ProPhoto linear RGB of the checker's patches in a RAW photo developed with
    ``white_balance`` ("camera" or multipliers, as :func:`grassd.calib.raw.develop_raw`), after
    refusing a photo whose patches clip (:func:`refuse_clipped_checker`): the patches to fit a
    colour correction to.

    Raises:
        ClippedCheckerError: a patch clips; the message names it and the fix.
        CornersOutsideImageError: a corner lies outside the photo.
    """
    p = Path(path)
    refuse_clipped_checker(p, corners, chart, white_balance)
    dev = develop_raw(p, white_balance=white_balance)
    check_inside(corners, dev.rgb.shape, p, "checker")
    return dev.checker_patches(corners)


def checker_white_balance(path: Path, corners: Sequence[Sequence[float]],
                          chart: ReferenceChart) -> tuple[float, float, float, float]:
    """LibRaw channel multipliers (R, G, B, G2) that develop the checker's grey patch to the
    chromaticity of its reference colour (a grey card is nearly, not exactly, neutral).

    Measured on the undeveloped Bayer data: ``c`` = the black-subtracted mean of each colour
    filter inside the grey patch. LibRaw develops ``out = rgb_cam . diag(wb) . c`` (then a fixed
    sRGB -> ProPhoto matrix), so ``wb = (rgb_cam^-1 . t) / c`` with ``t`` the reference grey in
    linear sRGB; normalised to green = 1. Where LibRaw reports no colour matrix the grey is
    made neutral (``wb = mean green / c``).


    Raises:
        ClippedCheckerError: a patch clips under these multipliers (module docstring).
        CheckerPhotoError: not an R/G/B Bayer sensor, an unsupported orientation, a grey patch
            too small or black.
    """
    path = Path(path)
    sensor = _read_sensor(path)
    img, colours, black, desc = sensor.img, sensor.colours, sensor.black, sensor.desc
    rgb_cam = sensor.rgb_cam
    quads = _raw_quads(sensor, corners, path)
    if len(desc) not in (3, 4) or set(desc[:3]) != set("RGB") or set(desc) - set("RGB"):
        raise CheckerPhotoError(f"{path.name}: colour filters {desc!r} are not an R/G/B Bayer "
                                "sensor; white balance from the checker needs one")
    # Clipping at the white level alone, before the multipliers are known, then (below) at the
    # levels where these multipliers saturate the development.
    _refuse(_clipping(sensor, quads, None), chart, path, sensor)
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
    _refuse(_clipping(sensor, quads, wb), chart, path, sensor)
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
    albedo = prophoto_to_rec709(chart.prophoto())  # scRGB: out-of-gamut patches go negative
    img, corners = checker_image(albedo, CHART_BODY_ALBEDO, width, height)
    return img * np.asarray(white_rgb709, dtype=np.float64), corners


def checker_image(patches: NDArray[np.float64], body: float | Sequence[float], width: int,
                  height: int) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Image (height, width, 3) of a checker's 24 ``patches`` (24, 3) (any per-patch colour:
    albedo, radiance, a sensor's response) on a chart body of colour ``body``, laid out as
    :data:`CHART_LAYOUT` (patches fill 80 % of their cells), and the (4, 2) corners of its
    patch area (TL, TR, BR, BL; pixels (x, y))."""
    corners = CHART_LAYOUT * np.array([width, height])
    hinv = homography(corners, [(0, 0), (1, 0), (1, 1), (0, 1)])
    yy, xx = np.mgrid[0:height, 0:width]
    uv = apply_homography(hinv, np.stack([xx + 0.5, yy + 0.5], axis=-1))
    rows, cols = CHART_GRID
    u, v = uv[..., 0], uv[..., 1]
    col = np.floor(u * cols).astype(int)
    row = np.floor(v * rows).astype(int)
    inside = ((u >= 0) & (u < 1) & (v >= 0) & (v < 1)
              & (np.abs(u * cols - col - 0.5) < 0.4) & (np.abs(v * rows - row - 0.5) < 0.4))
    img = np.empty((height, width, 3))
    img[...] = np.asarray(body, dtype=np.float64)
    idx = np.clip(row, 0, rows - 1) * cols + np.clip(col, 0, cols - 1)
    img[inside] = np.asarray(patches, dtype=np.float64)[idx[inside]]
    return img, corners
