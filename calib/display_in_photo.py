"""Find a grass display in a 360 photo, solve the camera's pose, and sample every pixel's top.

Input: two linear (H, W, 3) equirectangular photos (the repository's convention,
:mod:`grassd.sim.lighting`: texel (i, j) looks along ``uv_to_direction((j + 0.5) / W,
(i + 0.5) / H)`` in the camera frame) of a ``rows x cols`` display showing every pixel at its
shortest and at its longest grass; nothing else changes between them but photo noise.

Method (:func:`locate_display`):

1. Where the photos differ: the relative difference ``|L - S| / (|L| + |S| + eps)`` above a
   robust noise level (median + 8 x 1.4826 MAD) marks candidate texels; specks are removed by
   an opening, and the largest connected cluster (after a closing that bridges the gaps
   between pixel tops) is the display. The image is rolled so that the cluster never straddles
   the equirect seam.
2. A gnomonic (pinhole) view looking along the cluster's mean direction, focal length
   ``W / 2 pi`` pixels per radian (the equirect's angular resolution at the horizon), sampled
   bilinearly from the photo: straight display edges stay straight there.
3. Coarse corners: the convex hull of the cluster in that view, simplified to 4 vertices.
   Each edge is then refined to a fraction of a texel from intensity profiles across it: the
   signed difference ``(L - S) . g`` (``g`` the cluster's mean difference colour) is linear in
   the fraction of a texel the display covers, so the edge lies where the normalised profile's
   area says (a moment edge detector); a total-least-squares line is fitted to those edge
   points and adjacent lines are intersected.
4. The plane-to-view homography (display mm -> view pixels) from the 4 corners (Zhang 2000,
   "A flexible new technique for camera calibration", section 2; the 4-point DLT of
   :func:`grassd.calib.regions.homography`). A uniform pattern cannot tell the display's
   corners apart, so every labelling of the 4 corners is tried: mirrored ones put the camera
   below the plane, a wrong aspect (long side on the short one, or a wrong rows x cols) leaves
   a large angular residual, and of the two (four for a square display) that remain, the one
   that puts the camera on the row-0 side (smallest y: the viewer at -y of
   :mod:`grassd.sim.scene`) is kept.
5. The camera pose (:func:`solve_pose`) from the bearings of the 4 corners and of every pixel
   centre: a planar DLT on the bearings (Hartley & Zisserman, Multiple View Geometry, 2nd ed.,
   sections 4.1 and 7.1: ``b x (R X + t) = 0``), orthonormalised, then refined by
   least squares on the angular residuals.
6. Sampling regions: every equirect texel near the display whose centre direction maps
   (through the view and the inverse homography) into the central ``inner`` fraction (per
   side) of a pixel's top square belongs to that pixel.

Units: display dimensions in millimetres, camera position in metres (display frame: the plane
z = 0 centred on the origin, x along columns, y along rows, z up), angles in degrees, images
linear RGB. Errors: :class:`DisplayNotFoundError` and :class:`PoseError` (both
:class:`grassd.calib.errors.GeometryError`, so one line with what to fix at the command line).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from grassd.calib.errors import GeometryError
from grassd.calib.regions import apply_homography, homography

__all__ = [
    "CameraPose",
    "DisplayInPhoto",
    "DisplayNotFoundError",
    "GnomonicView",
    "PoseError",
    "locate_display",
    "pixel_means",
    "solve_pose",
]

#: Largest angular rms residual [deg] of an accepted pose.
MAX_RMS_DEG: float = 0.25
#: Fewest texels the display must cover in the photo (all pixels together).
MIN_TEXELS: int = 64
#: Largest accepted relative difference between the measured and the expected aspect ratio
#: (width / depth) of the display's outer rectangle.
ASPECT_TOLERANCE: float = 0.08
_REL_EPS = 1e-2  # relative-difference floor, x the median brightness
_NOISE_SIGMAS = 8.0
_PROFILE_HALF = 5.0  # half length of an edge profile [view px]
_PROFILE_STEP = 0.25


class DisplayNotFoundError(GeometryError):
    """The display cannot be found in the photos, or what was found does not match
    ``rows x cols`` (the message says what to check)."""


class PoseError(GeometryError):
    """The camera pose cannot be solved from the bearings, puts the camera below the display
    plane, or leaves too large an angular residual."""


# --------------------------------------------------------------------------- pose


@dataclass(frozen=True, eq=False)
class CameraPose:
    """Pose of a 360 camera relative to the display.

    ``rotation`` (3, 3) world-to-camera: a world vector ``v`` has camera coordinates
    ``rotation @ v``; ``position_m`` (3,) the camera centre in the display frame [m] (hand it
    to :func:`grassd.daemon.core.calibration.display_model.geometry_from_eye`); ``rms_deg`` the rms
    angle between the measured and the re-projected bearings [deg]; ``n_points`` how many
    points were fitted.
    """

    rotation: NDArray[np.float64]
    position_m: NDArray[np.float64]
    rms_deg: float
    n_points: int

    @property
    def translation_m(self) -> NDArray[np.float64]:
        """``t = -R C`` [m]: a world point X is at ``R X + t`` in the camera frame."""
        return -self.rotation @ self.position_m

    def bearings(self, points_m: ArrayLike) -> NDArray[np.float64]:
        """Unit camera-frame bearings (..., 3) of world points (..., 3) [m]."""
        p = (np.asarray(points_m, dtype=np.float64) - self.position_m) @ self.rotation.T
        return p / np.linalg.norm(p, axis=-1, keepdims=True)

    @property
    def tilt_deg(self) -> float:
        """Angle between the camera's up axis and the world's +z [deg]."""
        return float(np.degrees(np.arccos(np.clip(self.rotation[2, 2], -1.0, 1.0))))

    @property
    def yaw_deg(self) -> float:
        """Turn of the camera about +z [deg] (exact for an upright camera): the world direction
        of the camera's +x axis, counter-clockwise from world +x."""
        x = self.rotation.T @ np.array([1.0, 0.0, 0.0])
        return float(np.degrees(np.arctan2(x[1], x[0])))


def _as_plane_points(points_m: ArrayLike) -> NDArray[np.float64]:
    p = np.asarray(points_m, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] not in (2, 3):
        raise PoseError(f"points_m must be (n, 2) or (n, 3) metres; got shape {p.shape}")
    if p.shape[1] == 3:
        if np.abs(p[:, 2]).max(initial=0.0) > 1e-9:
            raise PoseError("points_m must lie on the display plane z = 0")
        p = p[:, :2]
    return p


def _pose_residuals(bearings: NDArray, x3: NDArray, rot: NDArray, t: NDArray) -> NDArray:
    p = x3 @ rot.T + t
    p /= np.linalg.norm(p, axis=1, keepdims=True)
    cross = np.linalg.norm(np.cross(bearings, p), axis=1)
    return np.arctan2(cross, np.sum(bearings * p, axis=1))


def _dlt(bearings: NDArray, xy: NDArray) -> NDArray:
    """Homography ``H`` (3, 3) with ``b ~ H (x, y, 1)``, points in front (``b . H p > 0``):
    the DLT on ``b x (H p) = 0`` with Hartley's normalisation of the plane points."""
    n = len(xy)
    centre = xy.mean(axis=0)
    scale = math.sqrt(2.0) / max(float(np.mean(np.linalg.norm(xy - centre, axis=1))), 1e-12)
    t_norm = np.array([[scale, 0, -scale * centre[0]], [0, scale, -scale * centre[1]],
                       [0, 0, 1.0]])
    p = np.column_stack([xy, np.ones(n)]) @ t_norm.T
    b1, b2, b3 = bearings[:, 0:1], bearings[:, 1:2], bearings[:, 2:3]
    z = np.zeros_like(p)
    a = np.concatenate([np.hstack([z, -b3 * p, b2 * p]),
                        np.hstack([b3 * p, z, -b1 * p]),
                        np.hstack([-b2 * p, b1 * p, z])])
    _, _, vt = np.linalg.svd(a)
    h = vt[-1].reshape(3, 3) @ t_norm  # b ~ h @ (x, y, 1)
    if np.sum(np.einsum("ij,nj->ni", h, np.column_stack([xy, np.ones(n)])) * bearings) < 0:
        h = -h
    return h


def _fit_pose(bearings: NDArray, xy: NDArray) -> CameraPose:
    """DLT + least squares, no acceptance checks (see :func:`solve_pose`)."""
    from scipy.optimize import least_squares
    from scipy.spatial.transform import Rotation

    n = len(xy)
    h = _dlt(bearings, xy)
    lam = 2.0 / (np.linalg.norm(h[:, 0]) + np.linalg.norm(h[:, 1]))
    r1, r2 = h[:, 0] * lam, h[:, 1] * lam
    u, _, vt = np.linalg.svd(np.column_stack([r1, r2, np.cross(r1, r2)]))
    rot = u @ np.diag([1.0, 1.0, np.linalg.det(u @ vt)]) @ vt
    t = h[:, 2] * lam
    x3 = np.column_stack([xy, np.zeros(n)])

    def resid(q: NDArray) -> NDArray:
        r = Rotation.from_rotvec(q[:3]).as_matrix()
        pp = x3 @ r.T + q[3:]
        pp /= np.linalg.norm(pp, axis=1, keepdims=True)
        return (pp - bearings).ravel()

    q0 = np.concatenate([Rotation.from_matrix(rot).as_rotvec(), t])
    sol = least_squares(resid, q0, method="lm" if 3 * n >= 6 else "trf", xtol=1e-14,
                        ftol=1e-14)
    rot = Rotation.from_rotvec(sol.x[:3]).as_matrix()
    t = sol.x[3:]
    ang = _pose_residuals(bearings, x3, rot, t)
    return CameraPose(rotation=rot, position_m=-rot.T @ t,
                      rms_deg=float(np.degrees(np.sqrt(np.mean(ang**2)))), n_points=n)


def solve_pose(bearings: ArrayLike, points_m: ArrayLike, *,
               max_rms_deg: float = MAX_RMS_DEG) -> CameraPose:
    """Planar perspective-n-point for a central (360) camera: the pose that sends known points
    on the display plane onto measured bearings.

    Args:
        bearings: (n, 3) directions (camera frame, need not be unit) towards the points.
        points_m: (n, 2) or (n, 3) points on the plane z = 0 (display frame) [m]; n >= 4, not
            all on a line.
        max_rms_deg: largest accepted rms angular residual [deg].

    Linear start: the homography ``b ~ [r1 r2 t] (x, y, 1)`` by the DLT on ``b x (H p) = 0``
    with Hartley's point normalisation (Hartley & Zisserman 2nd ed., algorithm 4.2; the planar
    case of section 7.1 / Zhang 2000 section 3.1), scaled so that ``|r1| + |r2| = 2``, signed
    so the points lie in front of their bearings, made a rotation by SVD; then
    ``scipy.optimize.least_squares`` (Levenberg-Marquardt) on the unit-vector residuals.

    Raises:
        PoseError: too few points, a camera below the plane (a mirrored correspondence), or
            an rms residual above ``max_rms_deg`` (wrong correspondences or wrong dimensions).
    """
    b = np.asarray(bearings, dtype=np.float64)
    xy = _as_plane_points(points_m)
    if b.ndim != 2 or b.shape[1] != 3 or len(b) != len(xy):
        raise PoseError(f"bearings must be (n, 3) matching points_m ({len(xy)}); got shape "
                        f"{b.shape}")
    if len(xy) < 4:
        raise PoseError(f"a planar pose needs at least 4 points; got {len(xy)}")
    if not (np.isfinite(b).all() and np.isfinite(xy).all()):
        raise PoseError("bearings and points_m must be finite")
    norm = np.linalg.norm(b, axis=1, keepdims=True)
    if (norm <= 0).any():
        raise PoseError("a bearing is the zero vector")
    pose = _fit_pose(b / norm, xy)
    if not pose.rms_deg <= max_rms_deg:
        raise PoseError(f"the pose leaves an rms angular residual of {pose.rms_deg:.3g} deg "
                        f"(accepted: {max_rms_deg:g} deg): the points do not match the bearings "
                        "(wrong correspondences or display dimensions)")
    if pose.position_m[2] <= 0:
        raise PoseError(f"the pose puts the camera {pose.position_m[2]:.3f} m below the display "
                        "plane: the points are matched to the bearings mirrored (check the "
                        "corner order)")
    return pose


# --------------------------------------------------------------------------- gnomonic view


@dataclass(frozen=True, eq=False)
class GnomonicView:
    """A virtual pinhole (gnomonic) view of the camera's sphere.

    ``centre`` (3,) unit optical axis in the camera frame, ``e1``/``e2`` (3,) unit image axes
    (x, y) orthogonal to it; ``focal_px`` pixels per unit tangent; view pixel (x, y) = principal
    point ``(cx, cy)`` + ``focal_px * (d . e1, d . e2) / (d . centre)``; ``size`` (width,
    height) of its raster [px] (pixel (ix, iy) covers [ix, ix+1) x [iy, iy+1)).
    """

    centre: NDArray[np.float64]
    e1: NDArray[np.float64]
    e2: NDArray[np.float64]
    focal_px: float
    cx: float
    cy: float
    size: tuple[int, int]

    def to_view(self, directions: ArrayLike) -> NDArray[np.float64]:
        """View coordinates (..., 2) of camera-frame directions (..., 3) (NaN behind it)."""
        d = np.asarray(directions, dtype=np.float64)
        z = d @ self.centre
        with np.errstate(divide="ignore", invalid="ignore"):
            zz = np.where(z > 1e-9, z, np.nan)
            return np.stack([self.cx + self.focal_px * (d @ self.e1) / zz,
                             self.cy + self.focal_px * (d @ self.e2) / zz], axis=-1)

    def to_direction(self, xy: ArrayLike) -> NDArray[np.float64]:
        """Unit camera-frame directions (..., 3) of view coordinates (..., 2)."""
        p = np.asarray(xy, dtype=np.float64)
        d = (self.centre + ((p[..., 0:1] - self.cx) / self.focal_px) * self.e1
             + ((p[..., 1:2] - self.cy) / self.focal_px) * self.e2)
        return d / np.linalg.norm(d, axis=-1, keepdims=True)


# --------------------------------------------------------------------------- result


@dataclass(frozen=True, eq=False)
class DisplayInPhoto:
    """Where a display lies in an equirect photo (:func:`locate_display`).

    ``corners_mm`` (4, 2) the display's outer corners (the outer corners of the corner pixels'
    tops) in display-plane mm: (-x, -y) = pixel 0's, (+x, -y) = pixel ``cols - 1``'s,
    (+x, +y) = the last pixel's, (-x, +y) = pixel ``N - cols``'s; ``corner_bearings`` (4, 3)
    their unit camera-frame bearings; ``homography`` (3, 3) display mm -> ``view`` pixels;
    ``centre_bearings`` (N, 3) every pixel centre's bearing; ``pose`` the camera pose from
    corners and centres.

    Sampling regions, flat: texel ``(texel_rows[k], texel_cols[k])`` of the photo belongs to
    pixel ``texel_pixel[k]`` (row-major index), sorted by pixel; :meth:`region` gives one
    pixel's texels. ``threshold`` the relative-difference level that marked the display.
    """

    rows: int
    cols: int
    pitch_mm: float
    top_mm: float
    inner: float
    image_shape: tuple[int, int]
    corners_mm: NDArray[np.float64]
    corner_bearings: NDArray[np.float64]
    homography: NDArray[np.float64]
    view: GnomonicView
    centre_bearings: NDArray[np.float64]
    pose: CameraPose
    texel_rows: NDArray[np.int64]
    texel_cols: NDArray[np.int64]
    texel_pixel: NDArray[np.int64]
    threshold: float

    @property
    def n_pixels(self) -> int:
        """Number of display pixels N = rows x cols."""
        return self.rows * self.cols

    def region_sizes(self) -> NDArray[np.int64]:
        """(N,) number of photo texels sampled for each pixel."""
        return np.bincount(self.texel_pixel, minlength=self.n_pixels)

    def region(self, i: int) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
        """(rows, cols) index arrays of the photo texels sampled for pixel ``i``."""
        lo, hi = np.searchsorted(self.texel_pixel, [i, i + 1])
        return self.texel_rows[lo:hi], self.texel_cols[lo:hi]

    def mask(self, i: int) -> NDArray[np.bool_]:
        """Boolean (H, W) mask of pixel ``i``'s sampling region."""
        m = np.zeros(self.image_shape, dtype=bool)
        m[self.region(i)] = True
        return m


def pixel_means(img: ArrayLike, located: DisplayInPhoto) -> NDArray[np.float64]:
    """(N, 3) mean linear RGB of every pixel's sampling region in ``img`` (H, W, 3), which must
    be a photo of the same size taken from the same pose as the located pair."""
    a = np.asarray(img)
    if a.shape[:2] != located.image_shape or a.ndim != 3:
        raise GeometryError(f"image shape {a.shape} differs from the located photos' "
                            f"{located.image_shape}")
    vals = a[located.texel_rows, located.texel_cols].astype(np.float64)
    n = located.n_pixels
    counts = np.bincount(located.texel_pixel, minlength=n).astype(np.float64)
    sums = np.stack([np.bincount(located.texel_pixel, weights=vals[:, k], minlength=n)
                     for k in range(a.shape[2])], axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return sums / counts[:, None]


# --------------------------------------------------------------------------- helpers


def _equirect_dirs(rows: NDArray, cols: NDArray, h: int, w: int) -> NDArray[np.float64]:
    theta = np.pi * (np.asarray(rows) + 0.5) / h
    phi = 2.0 * np.pi * (np.asarray(cols) + 0.5) / w
    s = np.sin(theta)
    return np.stack([s * np.cos(phi), s * np.sin(phi), np.cos(theta)], axis=-1)


def _bilinear(img: NDArray, directions: NDArray) -> NDArray:
    """Bilinear sample of an equirect image (H, W[, C]) in camera-frame directions (..., 3):
    texel centres are the samples; columns wrap at the seam, rows clamp at the poles."""
    h, w = img.shape[:2]
    d = directions
    u = (np.arctan2(d[..., 1], d[..., 0]) / (2.0 * np.pi)) % 1.0
    v = np.arccos(np.clip(d[..., 2] / np.linalg.norm(d, axis=-1), -1.0, 1.0)) / np.pi
    x = u * w - 0.5
    y = np.clip(v * h - 0.5, 0.0, h - 1.0)
    x0 = np.floor(x)
    y0 = np.minimum(np.floor(y), h - 2) if h > 1 else np.zeros_like(y)
    fx, fy = x - x0, y - y0
    x0 = x0.astype(np.int64) % w
    x1 = (x0 + 1) % w
    y0 = y0.astype(np.int64)
    y1 = np.minimum(y0 + 1, h - 1)
    if img.ndim == 3:
        fx, fy = fx[..., None], fy[..., None]
    return ((img[y0, x0] * (1 - fx) + img[y0, x1] * fx) * (1 - fy)
            + (img[y1, x0] * (1 - fx) + img[y1, x1] * fx) * fy)


def _simplify_to_quad(poly: NDArray) -> NDArray:
    """Drop the vertex of least triangle area until 4 remain (convex polygon, in order)."""
    p = [tuple(v) for v in poly]
    while len(p) > 4:
        a = np.array(p)
        prev, nxt = np.roll(a, 1, axis=0), np.roll(a, -1, axis=0)
        area = np.abs((a[:, 0] - prev[:, 0]) * (nxt[:, 1] - prev[:, 1])
                      - (a[:, 1] - prev[:, 1]) * (nxt[:, 0] - prev[:, 0]))
        p.pop(int(np.argmin(area)))
    return np.array(p, dtype=np.float64)


def _fit_line(pts: NDArray) -> tuple[NDArray, NDArray]:
    """Total-least-squares line (point, unit direction), one pass of outlier rejection."""
    keep = np.ones(len(pts), dtype=bool)
    for _ in range(2):
        c = pts[keep].mean(axis=0)
        _, _, vt = np.linalg.svd(pts[keep] - c)
        direction, normal = vt[0], vt[1]
        r = np.abs((pts - c) @ normal)
        lim = max(3.0 * 1.4826 * float(np.median(r[keep])), 0.1)
        keep = r <= lim
        if keep.sum() < 2:
            break
    return c, direction


def _intersect(c1: NDArray, d1: NDArray, c2: NDArray, d2: NDArray) -> NDArray:
    a = np.column_stack([d1, -d2])
    s = np.linalg.solve(a, c2 - c1)
    return c1 + s[0] * d1


# --------------------------------------------------------------------------- locate


def _rel_diff(short: NDArray, long: NDArray, eps: float | None = None
              ) -> tuple[NDArray, float]:
    """Relative difference ``|L - S| / (|L| + |S| + eps)`` (float32, (h, w)) and ``eps``."""
    s = short.astype(np.float32, copy=False)
    lg = long.astype(np.float32, copy=False)
    d = lg - s
    diff = np.sqrt(np.einsum("ijk,ijk->ij", d, d))
    bright = np.sqrt(np.einsum("ijk,ijk->ij", lg, lg)) + np.sqrt(np.einsum("ijk,ijk->ij", s, s))
    if eps is None:
        eps = _REL_EPS * max(float(np.median(bright)), 1e-30)
    return diff / (bright + np.float32(eps)), eps


def _largest_cluster(cand: NDArray, min_texels: int, wrap: bool
                     ) -> tuple[NDArray, int, tuple]:
    """(cluster mask in rolled coordinates, column roll, bounding slices) of the largest
    cluster of candidate texels, after an opening (specks) and a closing (gaps). ``wrap``
    (a whole equirect row): the columns are rolled to put the densest column mid-image so that
    no cluster straddles the seam."""
    from scipy import ndimage

    cand = ndimage.binary_opening(cand, structure=np.ones((3, 3), dtype=bool))
    if cand.sum() < min_texels:
        raise DisplayNotFoundError(
            "no display found: the all-short and all-long photos differ nowhere above noise; "
            "check that the camera sees the display, that both patterns were shown, and that "
            "the two photos are not the same shot")
    w = cand.shape[1]
    colsum = ndimage.uniform_filter1d(cand.sum(axis=0).astype(np.float64), 9, mode="wrap")
    shift = w // 2 - int(np.argmax(colsum)) if wrap else 0
    cand_r = np.roll(cand, shift, axis=1)
    closed = ndimage.binary_closing(cand_r, structure=np.ones((5, 5), dtype=bool))
    labels, nlab = ndimage.label(closed, structure=np.ones((3, 3), dtype=bool))
    sizes = np.bincount(labels.ravel(), weights=cand_r.ravel(), minlength=nlab + 1)
    sizes[0] = 0
    best = int(np.argmax(sizes))
    if sizes[best] < min_texels:
        raise DisplayNotFoundError(
            f"no display found: the largest region where the photos differ covers "
            f"{int(sizes[best])} texels (need {min_texels}); move the camera closer or use a "
            "higher resolution")
    sl = ndimage.find_objects((labels == best).astype(np.int8))[0]
    return (labels == best) & cand_r, shift, sl


@dataclass(frozen=True)
class _Differing:
    """Step 1's result: where the two photos differ. ``rel`` (h, w): the relative difference,
    computed inside the window (rows ``r0:r1``, columns ``win_cols``) and 0 elsewhere; ``thr``:
    the noise threshold; ``level``: the median relative difference over the display's texels
    ``rows``, ``cols``."""

    rel: NDArray
    thr: float
    level: float
    rows: NDArray
    cols: NDArray
    r0: int
    r1: int
    win_cols: NDArray


def _differing_region(short: NDArray, long: NDArray) -> _Differing:
    """Step 1 (module docstring): found on every second texel, then at full resolution in a
    window around what was found."""
    h, w = short.shape[:2]
    rel_c, eps = _rel_diff(short[::2, ::2], long[::2, ::2])
    sub = rel_c[::2, ::2]
    med = float(np.median(sub))
    thr = med + _NOISE_SIGMAS * 1.4826 * max(float(np.median(np.abs(sub - med))), 1e-6)
    _, shift_c, sl_c = _largest_cluster(rel_c > thr, max(MIN_TEXELS // 4, 4), True)
    pad = 8
    r0 = max(2 * sl_c[0].start - pad, 0)
    r1 = min(2 * sl_c[0].stop + pad, h)
    win_cols = (np.arange(2 * sl_c[1].start - pad, 2 * sl_c[1].stop + pad) - 2 * shift_c) % w
    if len(win_cols) >= w:
        win_cols = np.arange(w)
    rel_w, _ = _rel_diff(short[r0:r1][:, win_cols], long[r0:r1][:, win_cols], eps)
    blob, shift, sl = _largest_cluster(rel_w > thr, MIN_TEXELS, len(win_cols) == w)
    rel = np.zeros((h, w), dtype=np.float32)
    rel[r0:r1, win_cols] = rel_w
    rr, cc = np.nonzero(blob[sl])
    cc_orig = win_cols[(cc + sl[1].start - shift) % len(win_cols)]
    rr = rr + sl[0].start + r0
    return _Differing(rel, thr, float(np.median(rel[rr, cc_orig])), rr, cc_orig, r0, r1,
                      win_cols)


def _view_along(region: _Differing, h: int, w: int) -> GnomonicView:
    """Step 2: the gnomonic view along the region's mean direction, framing it with a margin
    (DisplayNotFoundError when the region spans too much of the sphere to be one display)."""
    dirs = _equirect_dirs(region.rows, region.cols, h, w)
    m = (dirs * np.sin(np.pi * (region.rows + 0.5) / h)[:, None]).sum(axis=0)
    m /= np.linalg.norm(m)
    max_angle = float(np.degrees(np.arccos(np.clip(dirs @ m, -1, 1).min())))
    if max_angle > 70.0:
        raise DisplayNotFoundError(
            f"the display spans {2 * max_angle:.0f} deg of the photo: too close to (or under) "
            "the camera to be located; move the camera farther from the display")
    ref = np.array([0.0, 0.0, 1.0]) if abs(m[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    e1 = np.cross(ref, m)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(m, e1)
    f = w / (2.0 * np.pi)
    xy = GnomonicView(m, e1, e2, f, 0.0, 0.0, (0, 0)).to_view(dirs)
    lo, hi = xy.min(axis=0), xy.max(axis=0)
    margin = 12.0 + 0.1 * float((hi - lo).max())
    vw = int(math.ceil(hi[0] - lo[0] + 2 * margin))
    vh = int(math.ceil(hi[1] - lo[1] + 2 * margin))
    return GnomonicView(m, e1, e2, f, float(margin - lo[0]), float(margin - lo[1]), (vw, vh))


def _display_quad(short: NDArray, long: NDArray, region: _Differing,
                  view: GnomonicView) -> NDArray:
    """Step 3: the display's corners in ``view`` (4, 2), counter-clockwise: the coarse
    quadrilateral of the region, then three passes of sub-texel edges from profiles of the
    signed difference."""
    from scipy import ndimage
    from scipy.spatial import ConvexHull, QhullError

    vw, vh = view.size
    gy, gx = np.mgrid[0:vh, 0:vw]
    grid = np.stack([gx + 0.5, gy + 0.5], axis=-1)
    rel_view = _bilinear(region.rel, view.to_direction(grid))
    vmask = rel_view > 0.5 * region.level
    lab, nl = ndimage.label(vmask)
    if nl == 0:
        raise DisplayNotFoundError("no display found in the rectified view of the differing "
                                   "region; check the photos")
    big = int(np.argmax(np.bincount(lab.ravel())[1:])) + 1
    py, px = np.nonzero(lab == big)

    pts = np.column_stack([px + 0.5, py + 0.5])
    try:
        hull = ConvexHull(pts)
    except QhullError as exc:
        raise DisplayNotFoundError("the differing region is a line, not a display; check the "
                                   "photos") from exc
    quad = _simplify_to_quad(pts[hull.vertices])  # counter-clockwise in (x, y)
    diff_mean = (long[region.rows, region.cols]
                 - short[region.rows, region.cols]).astype(np.float64).mean(axis=0)
    g = diff_mean / max(float(np.linalg.norm(diff_mean)), 1e-30)

    def signal(xy_pts: NDArray) -> NDArray:
        d = view.to_direction(xy_pts)
        return (_bilinear(long, d).astype(np.float64) - _bilinear(short, d)) @ g

    tau = np.arange(-_PROFILE_HALF, _PROFILE_HALF + 1e-9, _PROFILE_STEP)
    nin = int(round(1.5 / _PROFILE_STEP)) + 1
    for it in range(3):
        lines = []
        qh = np.column_stack([quad, np.ones(4)])
        sides = [np.cross(qh[k], qh[(k + 1) % 4]) for k in range(4)]
        for k in range(4):
            a, b = quad[k], quad[(k + 1) % 4]
            length = float(np.linalg.norm(b - a))
            e = (b - a) / length
            normal = np.array([e[1], -e[0]])  # outward for a counter-clockwise polygon
            # After the first pass, profiles run towards the vanishing point of the two
            # adjacent sides (the display's perpendicular to this side, seen in perspective):
            # they then stay on one pixel, parallel to the boundaries between pixels.
            vp = np.cross(sides[k - 1], sides[(k + 1) % 4])
            skip = _PROFILE_HALF + 3.0
            if length <= 2 * skip + 2:
                raise DisplayNotFoundError(
                    f"the display is only {length:.0f} view pixels across; move the camera "
                    "closer or use a higher resolution")
            s_along = np.arange(skip, length - skip, 0.5)
            base = a + s_along[:, None] * e
            if it == 0:
                dirs_p = np.broadcast_to(normal, base.shape)
            else:
                dirs_p = vp[:2] - vp[2] * base
                dirs_p = dirs_p / np.linalg.norm(dirs_p, axis=1, keepdims=True)
                dirs_p = dirs_p * np.sign(dirs_p @ normal)[:, None]
            prof_pts = base[:, None, :] + tau[None, :, None] * dirs_p[:, None, :]
            prof = signal(prof_pts.reshape(-1, 2)).reshape(len(s_along), len(tau))
            p_in = prof[:, :nin].mean(axis=1)
            p_out = prof[:, -nin:].mean(axis=1)
            contrast = p_in - p_out
            good = np.abs(contrast) > 0.5 * np.median(np.abs(contrast))
            if good.sum() < 4:
                raise DisplayNotFoundError("an edge of the display has no contrast between "
                                           "the two photos; check the photos")
            frac = (prof[good] - p_out[good, None]) / contrast[good, None]
            area = np.trapezoid(frac, tau, axis=1)  # = edge offset from tau[0]
            edge = base[good] + (tau[0] + area)[:, None] * dirs_p[good]
            lines.append(_fit_line(edge))
        quad = np.array([_intersect(*lines[k - 1], *lines[k]) for k in range(4)])
    return quad


def _labelled_corners(quad: NDArray, view: GnomonicView, corners_mm: NDArray, rows: int,
                      cols: int, max_rms_deg: float) -> NDArray:
    """Step 4: ``quad``'s corners in the order of ``corners_mm`` (the display's outer corners,
    mm): of every labelling, one that puts the camera above the plane, fits the pose within
    ``max_rms_deg`` and the display's aspect, and of those the camera on the row-0 side."""
    half_x, half_y = corners_mm[2]
    corner_dirs_view = view.to_direction(quad)
    # The quadrilateral's own shape: a homography from the unit square onto the corner
    # bearings is [a r1, r2, t] up to scale for a rectangle of aspect a (width / depth).
    unit = np.array([(0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0)])
    expected = half_x / half_y
    candidates = []
    for order in ([0, 1, 2, 3], [0, 3, 2, 1]):
        for k in range(4):
            idx = np.roll(order, -k)
            try:
                hs = _dlt(corner_dirs_view[idx], unit)
                pose = _fit_pose(corner_dirs_view[idx], corners_mm / 1000.0)
            except np.linalg.LinAlgError:
                continue
            aspect = float(np.linalg.norm(hs[:, 0]) / np.linalg.norm(hs[:, 1]))
            candidates.append((pose, idx, aspect))
    up = [c for c in candidates if c[0].position_m[2] > 0]
    ok = [c for c in up if c[0].rms_deg <= max_rms_deg
          and abs(math.log(c[2] / expected)) <= math.log(1.0 + ASPECT_TOLERANCE)]
    if not ok:
        found = min((c[2] for c in up), key=lambda a: abs(math.log(a / expected)),
                    default=float("nan"))
        found = max(found, 1.0 / found) if expected >= 1 else min(found, 1.0 / found)
        raise DisplayNotFoundError(
            f"the region where the photos differ does not have the shape of a {rows} x {cols} "
            f"display of {2 * half_x:.0f} x {2 * half_y:.0f} mm (aspect {expected:.3g}; "
            f"measured {found:.3g}); check rows, cols, pitch_mm and top_mm, and that nothing "
            "else changed between the two photos")
    _, idx, _ = min(ok, key=lambda c: c[0].position_m[1])
    return quad[idx]


def locate_display(short_img: ArrayLike, long_img: ArrayLike, rows: int, cols: int,
                   pitch_mm: float, top_mm: float, *, projection: str = "equirect",
                   inner: float = 0.6, max_rms_deg: float = MAX_RMS_DEG) -> DisplayInPhoto:
    """Find a ``rows x cols`` display in an equirect photo pair and solve the camera pose.

    Args:
        short_img, long_img: (H, W, 3) linear photos (W = 2 H) of the display with every pixel
            at its shortest and at its longest grass; all else unchanged but noise.
        rows, cols: the display's pixel grid; ``pitch_mm`` centre-to-centre spacing [mm],
            ``top_mm`` side of a pixel's visible top square [mm].
        projection: the photos' projection; only ``"equirect"``.
        inner: linear fraction (per side, 0 < inner <= 1) of each top square that is sampled
            around its centre (0.6 keeps 20 % of the side clear of each edge).
        max_rms_deg: largest accepted angular rms residual of the pose [deg].

    Returns the :class:`DisplayInPhoto` (module docstring for the method and references: its
    steps 1-6 are this function's).

    Raises:
        DisplayNotFoundError: the photos differ nowhere above noise, the differing region is
            too small, too close to the camera, or its shape does not fit ``rows x cols``.
        GeometryError: malformed arguments.
    """
    if projection != "equirect":
        raise GeometryError(f"projection {projection!r} is not supported; only 'equirect'")
    short = np.asarray(short_img)
    long = np.asarray(long_img)
    if short.ndim != 3 or short.shape[2] != 3 or short.shape != long.shape:
        raise GeometryError(f"short_img and long_img must be two (H, W, 3) photos of one size; "
                            f"got {short.shape} and {long.shape}")
    h, w = short.shape[:2]
    if w != 2 * h:
        raise GeometryError(f"an equirect photo has width = 2 x height; got {w} x {h}")
    if rows < 1 or cols < 1 or not (0 < top_mm <= pitch_mm) or not 0 < inner <= 1:
        raise GeometryError(f"need rows, cols >= 1, 0 < top_mm <= pitch_mm and 0 < inner <= 1; "
                            f"got {rows} x {cols}, top {top_mm} mm, pitch {pitch_mm} mm, "
                            f"inner {inner}")

    region = _differing_region(short, long)
    view = _view_along(region, h, w)
    quad = _display_quad(short, long, region, view)

    # 4. labelling and homography; 5. the pose from every corner and pixel centre
    half_x = (cols - 1) / 2.0 * pitch_mm + top_mm / 2.0
    half_y = (rows - 1) / 2.0 * pitch_mm + top_mm / 2.0
    corners_mm = np.array([(-half_x, -half_y), (half_x, -half_y), (half_x, half_y),
                           (-half_x, half_y)])
    r_i, c_i = np.meshgrid(np.arange(rows), np.arange(cols), indexing="ij")
    centres_mm = np.column_stack([((c_i - (cols - 1) / 2.0) * pitch_mm).ravel(),
                                  ((r_i - (rows - 1) / 2.0) * pitch_mm).ravel()])
    corners_view = _labelled_corners(quad, view, corners_mm, rows, cols, max_rms_deg)
    hom = homography(corners_mm, corners_view)
    corner_bearings = view.to_direction(corners_view)
    centre_bearings = view.to_direction(apply_homography(hom, centres_mm))
    all_b = np.concatenate([corner_bearings, centre_bearings])
    all_x = np.concatenate([corners_mm, centres_mm]) / 1000.0
    try:
        pose = solve_pose(all_b, all_x, max_rms_deg=max_rms_deg)
    except PoseError as exc:
        raise DisplayNotFoundError(f"the display was found but its pose is not plausible: "
                                   f"{exc}") from exc

    # 6. sampling regions
    tr, tc = np.meshgrid(np.arange(region.r0, region.r1), np.unique(region.win_cols),
                         indexing="ij")
    tr, tc = tr.ravel(), tc.ravel()
    mm = apply_homography(np.linalg.inv(hom), view.to_view(_equirect_dirs(tr, tc, h, w)))
    with np.errstate(invalid="ignore"):
        pc = np.round(mm[:, 0] / pitch_mm + (cols - 1) / 2.0)
        pr = np.round(mm[:, 1] / pitch_mm + (rows - 1) / 2.0)
        lim = inner * top_mm / 2.0
        inside = ((pc >= 0) & (pc < cols) & (pr >= 0) & (pr < rows)
                  & (np.abs(mm[:, 0] - (pc - (cols - 1) / 2.0) * pitch_mm) <= lim)
                  & (np.abs(mm[:, 1] - (pr - (rows - 1) / 2.0) * pitch_mm) <= lim))
    pix = (pr[inside] * cols + pc[inside]).astype(np.int64)
    order_k = np.argsort(pix, kind="stable")
    located = DisplayInPhoto(
        rows=rows, cols=cols, pitch_mm=float(pitch_mm), top_mm=float(top_mm),
        inner=float(inner), image_shape=(h, w), corners_mm=corners_mm,
        corner_bearings=corner_bearings, homography=hom, view=view,
        centre_bearings=centre_bearings, pose=pose, texel_rows=tr[inside][order_k],
        texel_cols=tc[inside][order_k], texel_pixel=pix[order_k], threshold=region.thr)
    empty = np.flatnonzero(located.region_sizes() == 0)
    if len(empty):
        raise DisplayNotFoundError(
            f"{len(empty)} pixel(s) (first: {int(empty[0])}) cover no texel of the photo "
            f"inside the central {inner:g} of their top; move the camera closer or use a "
            "higher resolution")
    return located
