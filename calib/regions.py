"""Measurement areas in images: mean linear RGB inside a quadrilateral, checker patch grids.

Coordinates are image pixels as (x, y) = (column, row); pixel (row r, column c) covers the square
[c, c+1) x [r, r+1) and belongs to an area when its centre (c + 0.5, r + 0.5) lies inside it
(points on an edge count as inside). This is the paper's measurement: the average of the linear
R, G, B channels inside the quadrilateral joining the four top corners of a grass pixel.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from grassd.calib.array_checks import as_float_array
from grassd.calib.charts import CHART_GRID
from grassd.calib.errors import GeometryError


def _check_quad(corners: ArrayLike, name: str = "corners") -> NDArray[np.float64]:
    q = as_float_array(corners, name, last_dim=2, ndim=2)
    if q.shape != (4, 2):
        raise GeometryError(f"{name} must be 4 (x, y) points; got shape {q.shape}")
    edges = np.roll(q, -1, axis=0) - q
    nxt = np.roll(edges, -1, axis=0)
    cross = edges[:, 0] * nxt[:, 1] - edges[:, 1] * nxt[:, 0]
    area = 0.5 * np.sum(q[:, 0] * np.roll(q[:, 1], -1) - np.roll(q[:, 0], -1) * q[:, 1])
    tol = 1e-12 * max(1.0, float(np.abs(q).max()) ** 2)
    if (cross > tol).any() and (cross < -tol).any():
        raise GeometryError(
            f"{name} {q.tolist()} do not form a convex quadrilateral; list the corners in order "
            "around the area (e.g. top-left, top-right, bottom-right, bottom-left)"
        )
    if abs(area) < 1.0:
        raise GeometryError(
            f"{name} enclose {abs(area):.3g} square pixels; give the four corners of a visible "
            "area (in order around it, not all on a line)"
        )
    return q


def _quad_window(
    shape: tuple[int, int], corners: ArrayLike
) -> tuple[int, int, int, int, NDArray[np.bool_]]:
    """(y0, y1, x0, x1, mask of that window) of a convex quadrilateral clipped to the image."""
    q = _check_quad(corners)
    h, w = int(shape[0]), int(shape[1])
    x0 = max(int(np.floor(q[:, 0].min() - 0.5)), 0)
    x1 = min(int(np.ceil(q[:, 0].max() + 0.5)), w)
    y0 = max(int(np.floor(q[:, 1].min() - 0.5)), 0)
    y1 = min(int(np.ceil(q[:, 1].max() + 0.5)), h)
    if x0 >= x1 or y0 >= y1:
        return 0, 0, 0, 0, np.zeros((0, 0), dtype=bool)
    px = (np.arange(x0, x1) + 0.5)[None, :]
    py = (np.arange(y0, y1) + 0.5)[:, None]
    e = np.roll(q, -1, axis=0) - q
    sign = np.sign(0.5 * np.sum(q[:, 0] * np.roll(q[:, 1], -1) - np.roll(q[:, 0], -1) * q[:, 1]))
    tol = 1e-9 * max(1.0, float(np.abs(q).max()) ** 2)
    mask = np.ones((y1 - y0, x1 - x0), dtype=bool)
    for k in range(4):  # half-plane test per edge: cross(edge, p - a) has the polygon's sign
        cr = e[k, 0] * (py - q[k, 1]) - e[k, 1] * (px - q[k, 0])
        mask &= sign * cr >= -tol
    return y0, y1, x0, x1, mask


def quad_mask(shape: tuple[int, int], corners: ArrayLike) -> NDArray[np.bool_]:
    """Boolean (H, W) mask of the pixels whose centres lie inside a convex quadrilateral.

    ``corners`` is (4, 2) (x, y) in order around the quadrilateral (either orientation).
    Vectorised half-plane tests over the quadrilateral's bounding box.
    """
    mask = np.zeros((int(shape[0]), int(shape[1])), dtype=bool)
    y0, y1, x0, x1, window = _quad_window(shape, corners)
    mask[y0:y1, x0:x1] = window
    return mask


def quad_max(image: ArrayLike, corners: ArrayLike) -> float:
    """Largest value of ``image`` (H, W) or (H, W, C) at the pixels whose centres lie inside a
    convex quadrilateral (-inf where it covers none), e.g. to find clipped raw values.

    >>> img = np.zeros((10, 10)); img[3, 4] = 7.0; img[0, 0] = 9.0
    >>> quad_max(img, [(3, 2), (8, 2), (8, 5), (3, 5)])
    7.0
    """
    img = np.asarray(image)
    y0, y1, x0, x1, mask = _quad_window(img.shape[:2], corners)
    if not mask.any():
        return float("-inf")
    return float(img[y0:y1, x0:x1][mask].max())


def quad_values(image: ArrayLike, corners: ArrayLike) -> NDArray:
    """The values of ``image`` (H, W) or (H, W, C) at the pixels whose centres lie inside a
    convex quadrilateral, as (n,) or (n, C) in row-major order (n = 0 where it covers none).

    >>> img = np.arange(100.0).reshape(10, 10)
    >>> quad_values(img, [(3, 2), (5, 2), (5, 3), (3, 3)]).tolist()
    [23.0, 24.0]
    """
    img = np.asarray(image)
    y0, y1, x0, x1, mask = _quad_window(img.shape[:2], corners)
    return img[y0:y1, x0:x1][mask]


def quad_mean(image: ArrayLike, corners: ArrayLike) -> NDArray[np.float64]:
    """Mean linear RGB (3,) of the pixels of ``image`` (H, W, 3) inside a convex quadrilateral.

    Sums in float64 over the bounding-box window without copying the pixels.

    >>> img = np.zeros((10, 10, 3)); img[2:5, 3:8] = 1.0
    >>> quad_mean(img, [(3, 2), (8, 2), (8, 5), (3, 5)]).tolist()
    [1.0, 1.0, 1.0]
    """
    img = np.asarray(image)
    if img.ndim != 3 or img.shape[2] != 3:
        raise GeometryError(f"image must be (H, W, 3) linear RGB; got shape {img.shape}")
    y0, y1, x0, x1, mask = _quad_window(img.shape[:2], corners)
    n = int(mask.sum())
    if n == 0:
        raise GeometryError(
            f"the quadrilateral {np.asarray(corners).tolist()} covers no pixel centre of the "
            f"{img.shape[1]}x{img.shape[0]} image; check the corner coordinates (x = column)"
        )
    window = img[y0:y1, x0:x1]
    total = np.sum(window, axis=(0, 1), where=mask[..., None], dtype=np.float64)
    if not np.isfinite(total).all():
        as_float_array(window[mask], "image (inside the quadrilateral)")  # raises with details
    return total / n


def homography(src: ArrayLike, dst: ArrayLike) -> NDArray[np.float64]:
    """3x3 projective map sending four (x, y) points ``src`` onto ``dst`` (direct linear solve)."""
    s = as_float_array(src, "src", last_dim=2, ndim=2)
    d = as_float_array(dst, "dst", last_dim=2, ndim=2)
    a = np.zeros((8, 8))
    b = d.reshape(-1)
    a[0::2, 0:2] = s
    a[0::2, 2] = 1.0
    a[0::2, 6:8] = -s * d[:, :1]
    a[1::2, 3:5] = s
    a[1::2, 5] = 1.0
    a[1::2, 6:8] = -s * d[:, 1:]
    try:
        h = np.linalg.solve(a, b)
    except np.linalg.LinAlgError as exc:
        raise GeometryError(f"the points {d.tolist()} do not define a quadrilateral") from exc
    return np.append(h, 1.0).reshape(3, 3)


def apply_homography(h: NDArray[np.float64], points: ArrayLike) -> NDArray[np.float64]:
    """Map (..., 2) points through a 3x3 homography."""
    p = np.asarray(points, dtype=np.float64)
    ph = p @ h[:, :2].T + h[:, 2]
    return ph[..., :2] / ph[..., 2:3]


def checker_patch_quads(
    chart_corners: ArrayLike,
    grid: tuple[int, int] = CHART_GRID,
    fraction: float = 0.5,
) -> NDArray[np.float64]:
    """Sampling quadrilaterals (rows*cols, 4, 2) of a checker's patches in reading order.

    Args:
        chart_corners: (4, 2) image (x, y) of the patch area's outer corners: top-left,
            top-right, bottom-right, bottom-left as the chart is meant to be read (top-left =
            first patch). Perspective is handled by a homography.
        grid: (rows, columns) of patches.
        fraction: linear fraction of each cell sampled around its centre (0 < f <= 1); 0.5
            keeps clear of the gaps between patches and of blur at their edges.
    """
    if not 0.0 < fraction <= 1.0:
        raise GeometryError(f"fraction must be in (0, 1]; got {fraction}")
    q = _check_quad(chart_corners, "chart_corners")
    h = homography([(0, 0), (1, 0), (1, 1), (0, 1)], q)
    rows, cols = grid
    r, c = np.meshgrid(np.arange(rows), np.arange(cols), indexing="ij")
    uc = ((c + 0.5) / cols).ravel()
    vc = ((r + 0.5) / rows).ravel()
    du = 0.5 * fraction / cols
    dv = 0.5 * fraction / rows
    offsets = np.array([(-du, -dv), (du, -dv), (du, dv), (-du, dv)])
    unit = np.stack([uc, vc], axis=-1)[:, None, :] + offsets[None]
    return apply_homography(h, unit)


def extract_checker_patches(
    image: ArrayLike,
    chart_corners: ArrayLike,
    grid: tuple[int, int] = CHART_GRID,
    fraction: float = 0.5,
) -> NDArray[np.float64]:
    """Mean linear RGB (rows*cols, 3) of every checker patch, in reading order.

    See :func:`checker_patch_quads` for the corner convention.
    """
    quads = checker_patch_quads(chart_corners, grid, fraction)
    return np.stack([quad_mean(image, quad) for quad in quads])
