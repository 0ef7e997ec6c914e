"""What a 360 camera sees of a grass display: an analytic equirectangular radiance image.

The display (:class:`grassd.sim.scene.DisplaySpec`) lies in the plane z = 0 centred on the
origin (x along columns, y along rows, row 0 nearest a viewer at -y, world metres, z up). Seen
from above, its outer rectangle (``cols * pitch_mm`` x ``rows * pitch_mm``) is the frame; each
pixel's visible top is the square of side ``PixelSpec.top_mm`` centred on its pixel centre and
has one radiance (the mean the camera would measure there). The grass's height and sides are
ignored: this is a flat, textured rectangle for testing how a photo is located and sampled
(:mod:`grassd.calib.display_in_photo`), not a path-traced view (that is
:mod:`grassd.sim.renderer`).

Camera: an upright 360 camera (Open Spherical Camera, e.g. RICOH THETA) at world point
``camera_m`` [m] whose up is world +z and which is turned about z by ``yaw_deg`` [deg,
counter-clockwise seen from above]. Its photo uses the repository's equirectangular convention
(:mod:`grassd.sim.lighting`) in the camera frame: a camera-frame direction ``d_c`` is the world
direction ``d_w = R_z(yaw) d_c``, so texel (row i, column j) looks along ``R_z(yaw)
uv_to_direction((j + 0.5) / W, (i + 0.5) / H)``. In world terms a world direction at map
coordinate ``u_w`` appears at ``u = u_w - yaw / 360``.

Background: the environment map ``env`` (world frame, repository convention) looked up with
:func:`grassd.sim.lighting.env_radiance` semantics (nearest texel) at every output texel's
centre direction: the map is resampled to the output size. Over the display every texel is
anti-aliased by ``supersample x supersample`` stratified rays (a box filter); the fraction of
rays that miss the display keeps the texel's background radiance.

Units: metres for positions, millimetres for display dimensions, degrees for yaw, linear
Rec.709 radiance (any consistent unit) for colours.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike, NDArray

from grassd.sim.errors import SceneError

if TYPE_CHECKING:
    from grassd.sim.scene import DisplaySpec

__all__ = [
    "camera_rotation",
    "display_footprint",
    "display_photo",
    "project_to_equirect",
    "top_corners_mm",
]

#: Largest number of rays traced at once (bounds memory: about 100 bytes a ray).
_CHUNK_RAYS = 1 << 21


def camera_rotation(yaw_deg: float) -> NDArray[np.float64]:
    """World-to-camera rotation (3, 3) of an upright camera turned by ``yaw_deg`` [deg] about
    +z: a world vector ``v`` has camera-frame coordinates ``R @ v`` (``R = R_z(-yaw)``)."""
    a = math.radians(float(yaw_deg))
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])


def project_to_equirect(points_m: ArrayLike, camera_m: ArrayLike, yaw_deg: float, width: int,
                        height: int) -> NDArray[np.float64]:
    """Continuous equirect image coordinates (..., 2) = (row, col) of world points (..., 3)
    [m] seen from ``camera_m`` with ``yaw_deg``; texel (i, j) covers [i, i+1) x [j, j+1), so
    its centre is (i + 0.5, j + 0.5). Columns are in [0, width)."""
    p = np.asarray(points_m, dtype=np.float64) - np.asarray(camera_m, dtype=np.float64)
    d = p @ camera_rotation(yaw_deg).T
    u = (np.arctan2(d[..., 1], d[..., 0]) / (2.0 * np.pi)) % 1.0
    v = np.arccos(np.clip(d[..., 2] / np.linalg.norm(d, axis=-1), -1.0, 1.0)) / np.pi
    return np.stack([v * height, u * width], axis=-1)


def top_corners_mm(display: DisplaySpec) -> NDArray[np.float64]:
    """(N, 4, 2) corners (x, y) [mm] of every pixel's top square, row-major pixels, corners in
    the order (-x, -y), (+x, -y), (+x, +y), (-x, +y) around the pixel centre."""
    centres = display.pixel_centres_m() * 1000.0
    h = display.pixel.top_mm / 2.0
    offs = np.array([(-h, -h), (h, -h), (h, h), (-h, h)])
    return centres[:, None, :] + offs[None, :, :]


def display_footprint(display: DisplaySpec, camera_m: ArrayLike, yaw_deg: float, width: int,
                      height: int, pad: int = 2) -> tuple[int, int, NDArray[np.int64]]:
    """Equirect window that holds the display's outer rectangle: (row0, row1, columns).

    ``columns`` are the column indices (wrapping at the seam, so possibly not increasing),
    rows ``row0 <= i < row1``; ``pad`` texels of margin. When the camera is above the display
    (the rectangle holds the nadir) the window is every column from ``row0`` to the bottom.
    """
    c = np.asarray(camera_m, dtype=np.float64)
    hx = display.cols * display.pitch_mm / 2000.0
    hy = display.rows * display.pitch_mm / 2000.0
    t = np.linspace(0.0, 1.0, 257)[:-1]
    edges = [np.stack([-hx + 2 * hx * t, np.full_like(t, -hy)], 1),
             np.stack([np.full_like(t, hx), -hy + 2 * hy * t], 1),
             np.stack([hx - 2 * hx * t, np.full_like(t, hy)], 1),
             np.stack([np.full_like(t, -hx), hy - 2 * hy * t], 1)]
    loop = np.concatenate(edges)
    pts = np.concatenate([loop, np.zeros((len(loop), 1))], axis=1)
    rc = project_to_equirect(pts, c, yaw_deg, width, height)
    row0 = max(int(math.floor(rc[:, 0].min())) - pad, 0)
    cols = np.unwrap(np.append(rc[:, 1], rc[0, 1]), period=width)
    if abs(cols[-1] - cols[0]) > width / 2 or (abs(c[0]) <= hx and abs(c[1]) <= hy):
        return row0, height, np.arange(width, dtype=np.int64)  # winds round the nadir
    row1 = min(int(math.ceil(rc[:, 0].max())) + pad, height)
    c0 = int(math.floor(cols.min())) - pad
    c1 = int(math.ceil(cols.max())) + pad
    n = min(c1 - c0, width)
    return row0, row1, (c0 + np.arange(n, dtype=np.int64)) % width


def _background(env: NDArray, yaw_deg: float, width: int, height: int,
                rows: NDArray[np.int64] | slice, cols: NDArray[np.int64]) -> NDArray:
    """Nearest-texel env radiance at the centres of output texels rows x cols (separable:
    an upright camera only shifts the map's columns by the yaw)."""
    h, w = env.shape[:2]
    r = np.arange(height)[rows] if isinstance(rows, slice) else rows
    v = (r + 0.5) / height
    er = np.minimum(np.floor(v * h).astype(np.int64), h - 1)
    u = ((cols + 0.5) / width + yaw_deg / 360.0) % 1.0
    ec = np.floor(u * w).astype(np.int64) % w
    return env[er][:, ec]


def display_photo(env: ArrayLike, camera_m: ArrayLike, yaw_deg: float, display: DisplaySpec,
                  pixel_radiance: ArrayLike, *, frame_radiance: ArrayLike = (0.0, 0.0, 0.0),
                  width: int = 4096, height: int = 2048, supersample: int = 2,
                  crop: bool = True) -> NDArray[np.float64]:
    """Equirectangular radiance photo (height, width, 3) float64, linear Rec.709, of a flat
    display seen by an upright 360 camera (module docstring for the conventions).

    Args:
        env: (h, w, 3) equirect environment radiance (world frame, repository convention).
        camera_m: (3,) camera position [m]; must be above the display plane (z > 0).
        yaw_deg: camera turn about +z [deg] (camera frame = world frame turned by it).
        display: rows, cols, pitch [mm] and the pixel's ``top_mm``.
        pixel_radiance: (N, 3) radiance of each pixel's top square, N = rows * cols, row-major.
        frame_radiance: (3,) radiance of the rest of the outer rectangle (the frame).
        width, height: output size (``width = 2 * height`` for a full sphere).
        supersample: rays per texel side over the display (box filter of s^2 stratified rays).
        crop: trace rays only in the window around the display (:func:`display_footprint`;
            identical result, far faster); ``False`` traces every texel (reference).

    Cost: the background is one gather (4096 x 2048: about 0.2 s here); the display window is
    ``s^2`` rays a texel.
    """
    env = np.asarray(env)
    if env.ndim != 3 or env.shape[2] != 3:
        raise SceneError(f"env must be an (h, w, 3) radiance map, got shape {env.shape}")
    cam = np.asarray(camera_m, dtype=np.float64).reshape(3)
    if not np.isfinite(cam).all() or cam[2] <= 0:
        raise SceneError(f"camera position {cam.tolist()} m must be finite and above the display "
                         "plane (z > 0)")
    n = display.rows * display.cols
    rad = np.asarray(pixel_radiance, dtype=np.float64)
    if rad.shape != (n, 3):
        raise SceneError(f"pixel_radiance must be ({n}, 3) for a {display.rows} x "
                         f"{display.cols} display, got shape {rad.shape}")
    frame = np.asarray(frame_radiance, dtype=np.float64).reshape(3)
    if width < 2 or height < 1 or supersample < 1:
        raise SceneError("width, height and supersample must be positive")
    out = _background(env, yaw_deg, width, height, slice(None),
                      np.arange(width)).astype(np.float64)
    if crop:
        row0, row1, cols = display_footprint(display, cam, yaw_deg, width, height)
    else:
        row0, row1, cols = 0, height, np.arange(width, dtype=np.int64)
    if row1 <= row0 or len(cols) == 0:
        return out
    # Every ray of a window row: per-row polar angles, per-column azimuths (separable).
    s = int(supersample)
    sub = (np.arange(s) + 0.5) / s
    yaw = math.radians(float(yaw_deg))
    phi = 2.0 * np.pi * ((cols[:, None] + sub[None, :]) / width).ravel() + yaw  # (nc * s,)
    cphi, sphi = np.cos(phi), np.sin(phi)
    half_w = display.cols * display.pitch_mm / 2.0
    half_h = display.rows * display.pitch_mm / 2.0
    half_top = display.pixel.top_mm / 2.0
    pitch = display.pitch_mm
    nc = len(cols)
    rows_per_chunk = max(1, _CHUNK_RAYS // (nc * s * s))
    for r0 in range(row0, row1, rows_per_chunk):
        r1 = min(r0 + rows_per_chunk, row1)
        theta = np.pi * ((np.arange(r0, r1)[:, None] + sub[None, :]) / height).ravel()
        st, ct = np.sin(theta)[:, None], np.cos(theta)[:, None]  # (nr * s, 1)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.where(ct < 0, -cam[2] / ct, np.inf)  # ray length to z = 0 per row
            x = (cam[0] + t * st * cphi[None, :]) * 1000.0  # mm, (nr * s, nc * s)
            y = (cam[1] + t * st * sphi[None, :]) * 1000.0
        inside = (np.abs(x) <= half_w) & (np.abs(y) <= half_h)  # inf/nan compare False
        xs = np.where(inside, x + half_w, 0.0)
        ys = np.where(inside, y + half_h, 0.0)
        ci = np.clip(np.floor(xs / pitch).astype(np.int64), 0, display.cols - 1)
        ri = np.clip(np.floor(ys / pitch).astype(np.int64), 0, display.rows - 1)
        on_top = (inside & (np.abs(xs - (ci + 0.5) * pitch) <= half_top)
                  & (np.abs(ys - (ri + 0.5) * pitch) <= half_top))
        colour = np.where(on_top[..., None], rad[ri * display.cols + ci],
                          np.where(inside[..., None], frame, 0.0))
        nr = r1 - r0
        colour = colour.reshape(nr, s, nc, s, 3).sum(axis=(1, 3)) / (s * s)
        cover = inside.reshape(nr, s, nc, s).mean(axis=(1, 3))
        if not cover.any():
            continue
        bg = out[r0:r1][:, cols]
        out[r0:r1, cols] = colour + (1.0 - cover[..., None]) * bg
    return out
