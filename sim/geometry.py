"""Procedural grass-pixel geometry as numpy arrays, and the 2D grid that accelerates tracing.

Everything here is in world metres (z up, display plane z = 0; see :mod:`grassd.sim.scene`).
Two kinds of primitive:

* **Blades**: flat, two-sided, tapered quads. A blade is planted at a pivot point ``p0`` on the
  plane z = 0, spans ``+-hw`` along a horizontal width axis ``a`` and rises along the unit axis
  ``u = (sin(alpha) l_x, sin(alpha) l_y, cos(alpha))``: it leans by ``alpha`` towards the
  horizontal direction ``l``. Its half width shrinks linearly over the last ``taper`` metres to
  ``tip_ratio * hw``. Yellow blades have a fixed length. Green blades have the length given to
  the renderer per measurement, and lean by ``alpha0 + splay * length / green_max`` (splay, the
  paper's stated cause of its theta = 90 deg error, is 0 by default); below the plane a green
  blade continues straight down to the cavity floor (a vertical quad).
* **Rectangles**: axis-aligned, two-sided: the base top around the slits, the base's outer walls
  and bottom, and each slit's cavity walls and floor.

:func:`build_scene` lays the blades out on jittered grids (seeded, so a layout is reproducible)
and bins every primitive's xy footprint into a uniform 2D grid; the kernel walks that grid along
the ray (2D DDA), testing each cell's primitives.
"""

from __future__ import annotations

import math
import threading
from collections import OrderedDict
from dataclasses import dataclass, fields, replace

import numpy as np

from grassd.sim.errors import SceneError
from grassd.sim.scene import DisplaySpec, PixelSpec

#: Material ids (row index into :attr:`SceneArrays.albedo`).
MAT_YELLOW, MAT_GREEN, MAT_BASE, MAT_CAVITY = 0, 1, 2, 3
MATERIAL_NAMES = ("yellow_grass", "green_grass", "base", "cavity")
#: Refuse geometry larger than this many primitives before allocating (about 2 GB of grid).
MAX_PRIMITIVES = 2_000_000
#: Grid cell side in blade widths (trade-off: primitives per cell vs cells per ray).
GRID_CELL_BLADE_WIDTHS = 1.5


@dataclass(frozen=True)
class Primitives:
    """The blades and rectangles of a laid-out display as float32/int32 rows (shapes and units
    in :class:`SceneArrays`): what a scene of any splay and lengths shares with others of its
    display."""

    blade_p0: np.ndarray
    blade_axis: np.ndarray
    blade_lean: np.ndarray
    blade_params: np.ndarray
    rect_axis: np.ndarray
    rect_bounds: np.ndarray
    rect_material: np.ndarray


@dataclass(frozen=True)
class SceneArrays(Primitives):
    """The traced scene as flat float32/int32 arrays (shapes named per field).

    Blades (``nb`` rows): ``blade_p0`` (nb, 3) pivot [m]; ``blade_axis`` (nb, 2) width axis;
    ``blade_lean`` (nb, 2) lean direction; ``blade_params`` (nb, 6) = (half width [m], fixed
    length [m] (0 for green), base lean alpha0 [rad], is_green (0/1), depth below the plane for
    green [m], material id).
    Rectangles (``nr`` rows): ``rect_axis`` (nr,) normal axis 0/1/2; ``rect_bounds`` (nr, 5) =
    (coordinate on the normal axis, lo0, hi0, lo1, hi1) on the other two axes in increasing
    order; ``rect_material`` (nr,).
    Grid: ``grid_origin`` (2,), ``grid_cell`` [m], ``grid_shape`` (nx, ny), ``cell_start``
    (nx*ny + 1,), ``cell_items`` (m,) primitive ids (blade i -> i, rectangle j -> nb + j),
    cell index = ix * ny + iy. ``z_range`` (2,) the slab every primitive lies in.
    ``albedo`` (4, 3) linear Rec.709 per material.
    """

    grid_origin: np.ndarray
    grid_cell: float
    grid_shape: tuple[int, int]
    cell_start: np.ndarray
    cell_items: np.ndarray
    z_range: np.ndarray
    albedo: np.ndarray
    taper_m: float
    tip_ratio: float
    splay_rad: float
    green_max_m: float
    quad_corners: np.ndarray
    specular: float = 0.0
    phong_exponent: float = 1.0

    @property
    def n_blades(self) -> int:
        return len(self.blade_p0)

    @property
    def n_rects(self) -> int:
        return len(self.rect_axis)


def _jittered_points(rng: np.random.Generator, x0: float, x1: float, y0: float, y1: float,
                     density: float, jitter: float) -> np.ndarray:
    """Points on a jittered square grid of ``density`` per mm^2 inside a rectangle (mm)."""
    if density <= 0 or x1 <= x0 or y1 <= y0:
        return np.zeros((0, 2))
    step = 1.0 / math.sqrt(density)
    nx = max(1, int(round((x1 - x0) / step)))
    ny = max(1, int(round((y1 - y0) / step)))
    sx, sy = (x1 - x0) / nx, (y1 - y0) / ny
    gx, gy = np.meshgrid((np.arange(nx) + 0.5) * sx + x0, (np.arange(ny) + 0.5) * sy + y0,
                         indexing="ij")
    pts = np.stack([gx.ravel(), gy.ravel()], axis=1)
    pts += rng.uniform(-jitter, jitter, pts.shape) * np.array([sx, sy])
    return pts


def _pixel_blades(spec: PixelSpec, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """Blade arrays (mm) of one pixel centred on the origin."""
    s = spec.top_mm / 2
    half_slit = spec.slit_width_mm / 2
    centres = spec.slit_centres_mm()
    hw0 = spec.blade_width_mm / 2
    # Yellow: on the top surface, away from the slits by half a blade width.
    yellow = _jittered_points(rng, -s + hw0, s - hw0, -s + hw0, s - hw0, spec.yellow_density,
                              spec.jitter)
    if len(centres):
        in_slit = (np.abs(yellow[:, 1, None] - centres[None, :]) < half_slit + hw0) & (
            np.abs(yellow[:, 0, None]) < spec.slit_length_mm / 2 + hw0)
        yellow = yellow[~in_slit.any(axis=1)]
    # Green: inside each slit.
    green = [
        _jittered_points(rng, -spec.slit_length_mm / 2 + hw0, spec.slit_length_mm / 2 - hw0,
                         c - half_slit + hw0, c + half_slit - hw0, spec.green_density, spec.jitter)
        for c in centres
    ]
    slit_of = np.concatenate([np.full(len(g), c) for g, c in zip(green, centres, strict=True)]) \
        if green else np.zeros(0)
    green = np.concatenate(green) if green else np.zeros((0, 2))

    ny, ng = len(yellow), len(green)
    n = ny + ng
    xy = np.concatenate([yellow, green])
    phi = rng.uniform(0, np.pi, n)
    axis = np.stack([np.cos(phi), np.sin(phi)], axis=1)
    # Lean: yellow in a random direction; green outwards from its slit's centre line (+-y),
    # perturbed, so that splay opens the tuft like real grass pushed through a slit.
    beta = rng.uniform(0, 2 * np.pi, n)
    if ng:
        side = np.where(xy[ny:, 1] >= slit_of, 0.5 * np.pi, -0.5 * np.pi)
        beta[ny:] = side + rng.normal(0, 0.35, ng)
    lean = np.stack([np.cos(beta), np.sin(beta)], axis=1)
    alpha0 = np.concatenate([
        np.radians(spec.yellow_lean_deg) * np.sqrt(rng.uniform(0, 1, ny)),
        np.radians(spec.green_lean_deg) * np.sqrt(rng.uniform(0, 1, ng)),
    ])
    hw = hw0 * (1 + rng.uniform(-spec.jitter, spec.jitter, n))
    length = np.concatenate([spec.yellow_height_mm * (1 + rng.uniform(-0.05, 0.05, ny)),
                             np.zeros(ng)])
    is_green = np.concatenate([np.zeros(ny), np.ones(ng)])
    depth = is_green * spec.cavity_depth_mm
    material = np.where(is_green > 0, MAT_GREEN, MAT_YELLOW)
    return {"xy": xy, "axis": axis, "lean": lean, "hw": hw, "length": length,
            "alpha0": alpha0, "is_green": is_green, "depth": depth, "material": material}


def _pixel_rects(spec: PixelSpec) -> list[tuple[int, float, float, float, float, float, int]]:
    """Axis-aligned rectangles (mm) of one pixel: (axis, coord, lo0, hi0, lo1, hi1, material)."""
    s, hb, dc = spec.top_mm / 2, spec.base_height_mm, spec.cavity_depth_mm
    hl, hs = spec.slit_length_mm / 2, spec.slit_width_mm / 2
    rects = []
    # Top surface: strips between slits across the whole width, and the slit end pieces.
    edges = [-s]
    for c in spec.slit_centres_mm():
        edges += [c - hs, c + hs]
    edges.append(s)
    for y0, y1 in zip(edges[0::2], edges[1::2], strict=True):
        if y1 > y0:
            rects.append((2, 0.0, -s, s, y0, y1, MAT_BASE))
    for c in spec.slit_centres_mm():
        if hl < s:
            rects.append((2, 0.0, -s, -hl, c - hs, c + hs, MAT_BASE))
            rects.append((2, 0.0, hl, s, c - hs, c + hs, MAT_BASE))
        # Cavity below the slit: walls and floor.
        rects.append((1, c - hs, -hl, hl, -dc, 0.0, MAT_CAVITY))
        rects.append((1, c + hs, -hl, hl, -dc, 0.0, MAT_CAVITY))
        rects.append((0, -hl, c - hs, c + hs, -dc, 0.0, MAT_CAVITY))
        rects.append((0, hl, c - hs, c + hs, -dc, 0.0, MAT_CAVITY))
        rects.append((2, -dc, -hl, hl, c - hs, c + hs, MAT_CAVITY))
    # Outer walls and bottom of the base.
    rects.append((0, -s, -s, s, -hb, 0.0, MAT_BASE))
    rects.append((0, s, -s, s, -hb, 0.0, MAT_BASE))
    rects.append((1, -s, -s, s, -hb, 0.0, MAT_BASE))
    rects.append((1, s, -s, s, -hb, 0.0, MAT_BASE))
    rects.append((2, -hb, -s, s, -s, s, MAT_BASE))
    return rects


def _bin(boxes: np.ndarray, origin: np.ndarray, cell: float, shape: tuple[int, int]
         ) -> tuple[np.ndarray, np.ndarray]:
    """Bin xy boxes (n, 4: xmin, ymin, xmax, ymax) into grid cells -> (cell_start, items)."""
    nx, ny = shape
    lo = np.floor((boxes[:, :2] - origin) / cell).astype(np.int64)
    hi = np.floor((boxes[:, 2:] - origin) / cell).astype(np.int64)
    lo = np.clip(lo, 0, [nx - 1, ny - 1])
    hi = np.clip(hi, 0, [nx - 1, ny - 1])
    cx, cy = hi[:, 0] - lo[:, 0] + 1, hi[:, 1] - lo[:, 1] + 1
    counts = cx * cy
    prim = np.repeat(np.arange(len(boxes)), counts)
    k = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
    ix = lo[prim, 0] + k // cy[prim]
    iy = lo[prim, 1] + k % cy[prim]
    cell_id = ix * ny + iy
    order = np.argsort(cell_id, kind="stable")
    cell_start = np.searchsorted(cell_id[order], np.arange(nx * ny + 1)).astype(np.int32)
    return cell_start, prim[order].astype(np.int32)


def check_lengths(spec: PixelSpec, lengths_mm) -> np.ndarray:
    """Green lengths (mm) as float64, or a SceneError: finite, non-empty, 0..green_max_mm."""
    lengths_mm = np.asarray(lengths_mm, dtype=np.float64)
    if lengths_mm.size == 0 or not np.all(np.isfinite(lengths_mm)):
        raise SceneError("lengths must be a non-empty list of finite numbers (mm)")
    if lengths_mm.min() < 0 or lengths_mm.max() > spec.green_max_mm:
        raise SceneError(f"green lengths must be within 0..{spec.green_max_mm:g} mm, got "
                         f"{lengths_mm.min():g}..{lengths_mm.max():g}")
    return lengths_mm


@dataclass(frozen=True)
class _Layout(Primitives):
    """What a scene keeps whatever its splay and lengths: the blades as laid out (``cat``, the
    per-blade arrays of :func:`_pixel_blades` over every pixel, mm), their float32 rows, the
    rectangles and their xy boxes [m], and the row-major pixel each blade and rectangle belongs
    to. Every array is read-only (layouts are shared)."""

    cat: dict[str, np.ndarray]
    rect_boxes: np.ndarray
    albedo: np.ndarray
    blade_pixel: np.ndarray
    rect_pixel: np.ndarray


def _readonly(a: np.ndarray) -> np.ndarray:
    a.flags.writeable = False
    return a


#: Layouts kept (least recently used dropped first), and the most blades a kept one may have (a
#: renderer's default capacity: larger displays, exported or checked, are laid out each time).
KEPT_LAYOUTS = 4
KEPT_LAYOUT_BLADES = 1 << 16
_layouts: OrderedDict[DisplaySpec, _Layout] = OrderedDict()
_layouts_lock = threading.Lock()


def _layout(display: DisplaySpec) -> _Layout:
    """The blade and rectangle layout of ``display``, kept for the next call with an equal
    display (a pure function of it: the blades are drawn from ``layout_seed``). Its pixel's
    ``splay_deg`` plays no part: :func:`build_scene` asks with 0, so that every splay of one
    display shares one layout."""
    with _layouts_lock:
        lay = _layouts.get(display)
        if lay is not None:
            _layouts.move_to_end(display)
            return lay
    lay = _draw_layout(display)
    if len(lay.blade_p0) <= KEPT_LAYOUT_BLADES:
        with _layouts_lock:
            _layouts[display] = lay
            while len(_layouts) > KEPT_LAYOUTS:
                _layouts.popitem(last=False)
    return lay


def _draw_layout(display: DisplaySpec) -> _Layout:
    """Lay out the blades and rectangles of ``display`` (see :class:`_Layout`)."""
    spec = display.pixel
    rng = np.random.default_rng(spec.layout_seed)
    one = _pixel_blades(spec, rng)
    centres_mm = display.pixel_centres_m() * 1000.0
    n_pix, nb1 = len(centres_mm), len(one["xy"])
    if n_pix * (nb1 + 40) > MAX_PRIMITIVES:
        raise SceneError(f"display of {n_pix} pixels x {nb1} blades exceeds the limit of "
                         f"{MAX_PRIMITIVES} primitives; lower the blade density or split it")
    # Every pixel gets its own layout (re-drawn), as real tufts differ, unless the display asks
    # for one layout everywhere (so per-pixel differences come from geometry alone).
    if display.same_layout:
        pixels = [one] + [{k: v.copy() for k, v in one.items()} for _ in range(n_pix - 1)]
    else:
        pixels = [one] + [_pixel_blades(spec, rng) for _ in range(n_pix - 1)]
    for p, c in zip(pixels, centres_mm, strict=True):
        p["xy"] = p["xy"] + c
    cat = {k: _readonly(np.concatenate([p[k] for p in pixels])) for k in one}
    nb = len(cat["xy"])

    mm = 1e-3
    blade_p0 = np.column_stack([cat["xy"] * mm, np.zeros(nb)]).astype(np.float32)
    blade_params = np.column_stack([cat["hw"] * mm, cat["length"] * mm, cat["alpha0"],
                                    cat["is_green"], cat["depth"] * mm,
                                    cat["material"]]).astype(np.float32)

    # Rectangles of every pixel: one pixel's, offset by each centre (the normal coordinate by
    # the centre's coordinate on that axis, the bounds by those on the other two).
    one_rects = np.array(_pixel_rects(spec), dtype=np.float64)  # (k, 7)
    axis1 = one_rects[:, 0].astype(np.int64)
    cx, cy = centres_mm[:, 0][:, None], centres_mm[:, 1][:, None]  # (n_pix, 1)
    zero = np.zeros_like(cx)
    offsets = {0: (cx, cy, zero), 1: (cy, cx, zero), 2: (zero, cx, cy)}
    off = np.zeros((n_pix, len(one_rects), 3))
    for ax, (o0, o1, o2) in offsets.items():
        sel = axis1 == ax
        off[:, sel, 0], off[:, sel, 1], off[:, sel, 2] = o0, o1, o2
    rects = np.empty((n_pix, len(one_rects), 7))
    rects[..., 0] = one_rects[:, 0]
    rects[..., 1] = one_rects[:, 1] + off[..., 0]
    rects[..., 2] = one_rects[:, 2] + off[..., 1]
    rects[..., 3] = one_rects[:, 3] + off[..., 1]
    rects[..., 4] = one_rects[:, 4] + off[..., 2]
    rects[..., 5] = one_rects[:, 5] + off[..., 2]
    rects[..., 6] = one_rects[:, 6]
    rects = rects.reshape(-1, 7)
    rect_axis = rects[:, 0].astype(np.int32)
    rect_bounds = (rects[:, 1:6] * mm).astype(np.float32)
    rect_material = rects[:, 6].astype(np.int32)
    b = rect_bounds.astype(np.float64)
    rect_boxes = np.empty((len(rects), 4))
    for ax, cols in ((0, (0, 1, 0, 2)),    # x = coord, y in [lo0, hi0]
                     (1, (1, 0, 2, 0)),    # y = coord, x in [lo0, hi0]
                     (2, (1, 3, 2, 4))):   # z = coord, x in lo0..hi0, y in lo1..hi1
        sel = rect_axis == ax
        rect_boxes[sel] = b[sel][:, list(cols)]
    albedo = spec.albedo_linear
    return _Layout(cat=cat, blade_p0=_readonly(blade_p0),
                   blade_axis=_readonly(cat["axis"].astype(np.float32)),
                   blade_lean=_readonly(cat["lean"].astype(np.float32)),
                   blade_params=_readonly(blade_params), rect_axis=_readonly(rect_axis),
                   rect_bounds=_readonly(rect_bounds), rect_material=_readonly(rect_material),
                   rect_boxes=_readonly(rect_boxes),
                   albedo=_readonly(albedo.astype(np.float32)),
                   blade_pixel=_readonly(np.repeat(np.arange(n_pix), [len(p["xy"])
                                                                      for p in pixels])),
                   rect_pixel=_readonly(np.repeat(np.arange(n_pix), len(one_rects))))


def _unsplayed(display: DisplaySpec) -> DisplaySpec:
    """The display a layout is kept for: its pixel's splay plays no part (:func:`_layout`)."""
    spec = display.pixel
    return replace(display, pixel=replace(spec, splay_deg=0.0)) if spec.splay_deg else display


def primitive_pixels(display: DisplaySpec) -> tuple[np.ndarray, np.ndarray]:
    """The row-major pixel index of every blade (nb,) and every rectangle (nr,) of
    ``display``'s scenes, in the order of :func:`build_scene`'s arrays."""
    lay = _layout(_unsplayed(display))
    return lay.blade_pixel, lay.rect_pixel


def build_scene(display: DisplaySpec, lengths_mm: np.ndarray) -> SceneArrays:
    """Build the traced scene for a display, conservative for every length in ``lengths_mm``.

    Lengths are green grass lengths in mm above the base top (0 .. ``green_max_mm``).

    The blades and rectangles of a display are laid out once and kept (the last few displays,
    whatever their splay; their arrays are read-only and shared by the scenes built from them):
    a scene of another splay or other lengths only bins the primitives into its grid again.
    """
    spec = display.pixel
    lengths_mm = check_lengths(spec, lengths_mm)
    lay = _layout(_unsplayed(display))
    cat = lay.cat

    # Footprints (xy boxes, m) of blades at their widest lean over all lengths.
    mm = 1e-3
    splay = math.radians(spec.splay_deg)
    lmax = lengths_mm.max() * mm
    length = np.where(cat["is_green"] > 0, lmax, cat["length"] * mm)
    alpha = cat["alpha0"] + cat["is_green"] * splay * (lengths_mm.max() / spec.green_max_mm)
    tip = cat["xy"] * mm + cat["lean"] * (np.sin(alpha) * length)[:, None]
    reach = np.abs(cat["axis"]) * (cat["hw"] * mm)[:, None]
    p = cat["xy"] * mm
    blade_boxes = np.column_stack([np.minimum(p, tip) - reach, np.maximum(p, tip) + reach])
    boxes = np.concatenate([blade_boxes, lay.rect_boxes])
    margin = 1e-4
    origin = boxes[:, :2].min(axis=0) - margin
    extent = boxes[:, 2:].max(axis=0) + margin - origin
    cell = max(spec.blade_width_mm * GRID_CELL_BLADE_WIDTHS * mm, float(extent.max()) / 2048)
    shape = (int(math.ceil(extent[0] / cell)), int(math.ceil(extent[1] / cell)))
    cell_start, cell_items = _bin(boxes, origin, cell, shape)

    z_top = max(lmax, float(np.max(cat["length"], initial=0.0)) * mm) + 1e-4
    z_range = np.array([-spec.base_height_mm * mm - 1e-4, z_top], dtype=np.float32)
    s = spec.top_mm / 2 * mm
    quad = np.array([[-s, -s, 0.0], [s, -s, 0.0], [s, s, 0.0], [-s, s, 0.0]])
    shared = {f.name: getattr(lay, f.name) for f in fields(Primitives)}
    return SceneArrays(
        **shared, grid_origin=origin.astype(np.float32),
        grid_cell=float(cell), grid_shape=shape, cell_start=cell_start, cell_items=cell_items,
        z_range=z_range, albedo=lay.albedo, taper_m=spec.taper_mm * mm,
        tip_ratio=spec.blade_tip_ratio, splay_rad=splay, green_max_m=spec.green_max_mm * mm,
        quad_corners=quad, specular=spec.specular, phong_exponent=spec.phong_exponent,
    )


def blade_rise(sc: SceneArrays, green_length_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Rise axis ``u`` (nb, 3) and length (nb,) [m] of every blade for a green length [m].

    The numpy twin of the renderer's ``blade_axes`` (same formula: green blades take the given
    length and lean by ``alpha0 + splay * length / green_max``).
    """
    green = sc.blade_params[:, 3] > 0.5
    alpha = sc.blade_params[:, 2].astype(np.float64) + green * (
        sc.splay_rad * green_length_m / sc.green_max_m)
    length = np.where(green, green_length_m, sc.blade_params[:, 1])
    sa = np.sin(alpha)
    u = np.column_stack([sa * sc.blade_lean[:, 0], sa * sc.blade_lean[:, 1], np.cos(alpha)])
    return u, length


def triangle_mesh(sc: SceneArrays, green_length_m: float) -> dict[str, tuple[np.ndarray,
                                                                             np.ndarray]]:
    """The exact traced surfaces as triangle meshes per material name: {name: (V (n, 3) [m],
    F (m, 3) int32)}. Blade outlines are the six-vertex tapered polygons the kernel intersects;
    zero-area triangles are dropped."""
    u, length = blade_rise(sc, green_length_m)
    p0 = sc.blade_p0.astype(np.float64)
    a = np.column_stack([sc.blade_axis, np.zeros(sc.n_blades)]).astype(np.float64)
    hw = sc.blade_params[:, 0].astype(np.float64)
    r = sc.tip_ratio
    h_mid = np.maximum(0.0, length - sc.taper_m)
    heights = np.stack([np.zeros_like(length), h_mid, length], axis=1)        # (nb, 3)
    frac = np.clip((length[:, None] - heights) / sc.taper_m, 0.0, 1.0)
    half = hw[:, None] * (r + (1 - r) * frac)                                 # (nb, 3)
    centre = p0[:, None, :] + heights[..., None] * u[:, None, :]              # (nb, 3, 3)
    left = centre - half[..., None] * a[:, None, :]
    right = centre + half[..., None] * a[:, None, :]
    # vertex order per blade: L0 R0 L1 R1 L2 R2
    verts = np.stack([left, right], axis=2).reshape(-1, 6, 3)
    quads = np.array([[0, 1, 3], [0, 3, 2], [2, 3, 5], [2, 5, 4]])
    green = sc.blade_params[:, 3] > 0.5
    # Green blades continue straight down into the cavity: a vertical rectangle.
    depth = sc.blade_params[:, 4].astype(np.float64)
    low_c = np.stack([p0 - np.column_stack([np.zeros((sc.n_blades, 2)), depth]), p0], axis=1)
    low = np.stack([low_c - hw[:, None, None] * a[:, None, :],
                    low_c + hw[:, None, None] * a[:, None, :]], axis=2).reshape(-1, 4, 3)

    out_v: dict[int, list[np.ndarray]] = {}
    out_f: dict[int, list[np.ndarray]] = {}

    def add(mat: int, v: np.ndarray, tris: np.ndarray) -> None:
        """v: (k, nv, 3) polygons sharing the same triangle pattern ``tris``."""
        if len(v) == 0:
            return
        tri = v[:, tris]                                                      # (k, nt, 3, 3)
        area = np.linalg.norm(np.cross(tri[..., 1, :] - tri[..., 0, :],
                                       tri[..., 2, :] - tri[..., 0, :]), axis=-1)
        keep = area > 1e-14
        tri = tri[keep]
        out_v.setdefault(mat, []).append(tri.reshape(-1, 3))
        out_f.setdefault(mat, [])
        out_f[mat].append(np.arange(len(tri) * 3).reshape(-1, 3))

    mats = sc.blade_params[:, 5].astype(int)
    for mat in (MAT_YELLOW, MAT_GREEN):
        sel = (mats == mat) & (length > 0)
        add(mat, verts[sel], quads)
    add(MAT_GREEN, low[green], np.array([[0, 1, 3], [0, 3, 2]]))
    # Rectangles: four corners from (coord, lo0, hi0, lo1, hi1) on their axes.
    b = sc.rect_bounds.astype(np.float64)
    corners_uv = np.array([[0, 0], [1, 0], [1, 1], [0, 1]])
    c0 = b[:, 1][:, None] + (b[:, 2] - b[:, 1])[:, None] * corners_uv[:, 0]  # (nr, 4)
    c1 = b[:, 3][:, None] + (b[:, 4] - b[:, 3])[:, None] * corners_uv[:, 1]
    coord = np.repeat(b[:, 0:1], 4, axis=1)
    rect_v = np.empty((sc.n_rects, 4, 3))
    for axis, (i0, i1) in {0: (1, 2), 1: (0, 2), 2: (0, 1)}.items():
        sel = sc.rect_axis == axis
        rect_v[sel, :, axis] = coord[sel]
        rect_v[sel, :, i0] = c0[sel]
        rect_v[sel, :, i1] = c1[sel]
    for mat in np.unique(sc.rect_material):
        add(int(mat), rect_v[sc.rect_material == mat], np.array([[0, 1, 2], [0, 2, 3]]))
    return {MATERIAL_NAMES[m]: (np.concatenate(out_v[m]), _renumber(out_f[m])) for m in out_v}


def _renumber(faces: list[np.ndarray]) -> np.ndarray:
    """Concatenate face lists whose vertex arrays are concatenated too."""
    offset, parts = 0, []
    for f in faces:
        parts.append(f + offset)
        offset += int(f.max()) + 1 if f.size else 0
    return np.concatenate(parts).astype(np.int32)
