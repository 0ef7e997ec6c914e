"""The Taichi path tracer: one ``@ti.data_oriented`` class that owns its fields.

Physically based Monte Carlo path tracing of the grass-pixel scene (:mod:`grassd.sim.geometry`)
under an importance-sampled equirectangular environment plus an optional directional sun.

* Transport: Lambertian surfaces (optionally plus a normalised modified-Phong glossy lobe,
  off by default), next-event estimation of the environment (sampled per normal bin in
  proportion to luminance x solid angle x a cosine bound, :mod:`grassd.sim.env_sampler`) and
  of the sun (ray-traced shadow), cosine-weighted BSDF sampling, the two environment
  strategies combined by Veach's balance heuristic (it leaves the OGCD less variance than the
  power heuristic). The last surface of a path of several takes light samples alone: its BSDF
  sample would only ask whether the environment is visible, one more upward ray for a small
  share of that surface's direct light. Up to ``max_bounces`` surface interactions, Russian
  roulette from surface ``roulette_from`` on (0 = the first a path meets; by default 2, the
  third; survivors weighted by the inverse survival probability, so the estimate stays
  unbiased for that depth; the decision is a random number of the path, the same at every
  length).
* Measurement: the mean linear RGB radiance over the image-plane quad that joins the projections
  of the pixel's four top corners (the paper's measurement area), estimated by stratified
  sampling of the bilinear parametrisation of that quad, weighted by its Jacobian so the
  estimate is the mean over image area. No image is formed.
* Uncertainty: ``replicates`` independently randomised stratified estimates; their spread gives
  the Monte Carlo standard error. Replicate means are returned, so downstream non-linear
  quantities (Lab, OGCD) can be given errors that include the correlation between lengths
  (the daemon uses the replicates' covariance, :func:`grassd.calib.ogcd.ogcd_from_samples`).
* Common random numbers: a camera path's random numbers depend on (seed, replicate, sample) but
  not on the grass length, so all lengths are traced with the same sample sequence and OGCD
  differences are smooth. With the same seed the result is bit-reproducible (each path writes
  its own slot; a float64 kernel then sums each (length, replicate) group serially).
* One path, every length: a camera path is traced at the shortest length, and every trace
  reports the least green length at which some green blade it missed would come in front of
  its hit (or block its shadow ray). Lengths below the least such length over the path give
  the same surfaces, points and random numbers, hence the same radiance bit for bit, and take
  it without tracing; the path is traced again at the first length past it. A green blade's
  outline grows with its length (longer blades hold shorter ones), so a path is traced again
  only at about the lengths where its radiance actually changes. A trace at a longer length
  keeps the answers of the path's rays up to the first one that may change there (each ray
  has its own growth length), so only the rest of the path is traced again. Splay turns a
  green blade's plane with its length: a ray that comes near a green blade it may meet at
  some length of the launch (one the culling does not skip), or is blocked by one, takes the
  current length as its growth length, and rays that stay clear of every green blade keep
  theirs; so a path is traced at nearly every length, but keeps its rays, light samples and
  bounces up to the first vertex that moves.
* Sampling: randomised quasi-Monte Carlo. Every pair of dimensions (quad position, light
  samples, bounce directions) takes the 2D Sobol' points, Owen-scrambled and index-shuffled per
  (replicate, pair) (:func:`grassd.sim.tifuncs.owen_sobol_pair`): the strata**2 paths of a
  replicate form a (0, m, 2)-net in each pair, and replicates are independent randomisations,
  so their spread stays an honest standard error. The first surface a path meets takes
  ``light_samples`` environment samples, consecutive points of the light pair's net, so that
  they are stratified over the hemisphere at that surface as well as across paths; later
  surfaces take one.

Numpy in, numpy out: :meth:`Renderer.characteristic` takes a :class:`~grassd.sim.scene.DisplaySpec`,
a ``Lighting`` (from :mod:`grassd.sim.lighting`), a viewpoint and lengths (mm), and returns a
:class:`Measurement`. Call :func:`grassd.sim.backend.init` before constructing a Renderer.

What each choice here measured, and what was tried and dropped: docs/renderer/measurements.md.
"""


import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field, fields

import numpy as np

from grassd.sim import geometry
from grassd.sim import tifuncs as tf
from grassd.sim.albedo_terms import (
    CODE_BASE,
    DEEP_CODE_BASE,
    MAX_DEGREE,
    MAX_TERM_DEGREE,
    N_MONOMIALS,
    N_SYMBOLS,
    SPECULAR,
    TERM_DEGREE,
    TERM_SLOTS,
    AlbedoTerms,
    code_table,
    n_monomials,
)
from grassd.sim.backend import is_initialised, runs_on_host, ti
from grassd.sim.camera import frame_quad, image_quad
from grassd.sim.env_sampler import (
    COARSE_COLS_MAX,
    COARSE_ROWS_MAX,
    NORMAL_BINS_SIDE,
    build_binned_sampler,
)
from grassd.sim.errors import SceneError, SimError
from grassd.sim.geometry import SceneArrays, blade_rise, build_scene, check_lengths
from grassd.sim.hdri import RENDERER_TEXELS
from grassd.sim.interrupt import Interrupt
from grassd.sim.lighting import Lighting
from grassd.sim.scene import DisplaySpec, RenderSettings, Viewpoint

vec3 = tf.vec3
vec4 = ti.types.vector(4, ti.f32)
EPS = 2e-6  # m: offset of secondary ray origins along the facing normal
ZCULL = 1e-5  # m: margin of the per-cell height culling of primitives
# paths: the fewest a launch takes by default: small launches ran slower per path under
# Taichi's own CPU loop scheme (in tasks of 32, grassd.sim.backend.COMPILE_OPTIONS, they do not).
MIN_LAUNCH_PATHS = 1 << 17
PREVIEW_MAX = 1024  # largest preview image side (pixels)
# Russian roulette (RenderSettings.roulette_from, the surface index from which it plays, is 2 by
# default: the third surface): its light and everything after it are a small share of the
# quad's radiance but a large share of a path's rays (docs/renderer/measurements.md).
RR_SURVIVAL = 0.5
# Rays of a path whose answers are kept for its next length (trace_memo): enough for the
# default path (4 + 1 light samples, sun, 3 bounces: 12 rays); later rays are traced again.
# A row: t, normal (3), material, growth length; a light sample's row also its direction (3)
# and contribution (3, linear RGB), so that a vertex that stays does not sample the environment
# again; a bounce ray's row the direction (3), throughput weight (3) and pdf its BSDF sample
# gave, so that it does not sample its bounce again either.
MEMO_RAYS = 16
MEMO_COLS = 13
# m: a shadow ray that got through at a shorter length is blocked at any length this far past
# its growth length (the length from which a green blade it missed holds the point where the
# ray crosses the blade's plane: tifuncs.hit_growing_blade, which takes 0.1 um off it), so it
# is not traced again there.
GROWN_IN = 1e-6
# The recording mode (albedo_terms): each thread sums TERM_BLOCK camera paths of one (length,
# replicate) serially into its own row of term_acc, so the sums do not depend on scheduling.
# Small blocks give Taichi's adaptive CPU scheduling enough iterations to balance the cores.
TERM_BLOCK = 16
TERM_THREADS = 1 << 14
# The deep recording (albedo_terms with max_bounces above 3) sums its monomials in a field of
# DEEP_TERM_ROWS (thread, monomial) rows per degree, at least DEEP_BLOCK paths a thread.
DEEP_TERM_ROWS = 1 << 21
DEEP_BLOCK = 64
LOBE_TERM_DIM = 4096  # first random-number dimension of the deep recording's lobe choices


@dataclass(frozen=True)
class Capacity:
    """Field sizes allocated once per :class:`Renderer` (kernels compile once for them)."""

    blades: int = 1 << 16
    rects: int = 1 << 13
    cells: int = 1 << 20
    items: int = 1 << 21
    env_texels: int = RENDERER_TEXELS
    env_rows: int = 1024
    paths: int = 1 << 22


@dataclass(frozen=True)
class Measurement:
    """Simulated measurement of one viewpoint at several green lengths.

    ``rgb_linear`` (n, 3): mean linear Rec.709 radiance over the measurement quad, in the units of
    the scaled environment (nits when the map was scaled to lux). ``rgb_stderr`` (n, 3): its Monte
    Carlo standard error. ``rgb_replicates`` (R, n, 3): the independent replicate means (same
    random numbers across lengths within a replicate). ``seconds``: compile, trace, total.
    ``paths_traced``: camera paths actually traced, at most n x ``samples_per_length``; a path
    is traced again only at a length from which on its rays may meet other surfaces.
    ``rays_traced``: rays (camera, bounce and shadow) actually traced; a path traced again
    keeps the answers of its rays up to the first vertex that moves.
    """

    viewpoint: Viewpoint
    lengths_mm: np.ndarray
    rgb_linear: np.ndarray
    rgb_stderr: np.ndarray
    rgb_replicates: np.ndarray
    samples_per_length: int
    seconds: dict[str, float] = field(default_factory=dict)
    paths_traced: int = 0
    rays_traced: int = 0


@dataclass(frozen=True)
class QuadHits:
    """What the camera's rays through a pixel's measurement quad meet first, at each length.

    ``lengths_mm`` (L,) green lengths (mm); ``xy_m`` (L, S, 2) each ray's first hit in the
    display's plane (m, the coordinates of :meth:`~grassd.sim.scene.DisplaySpec.pixel_centres_m`;
    NaN where it escaped); ``material`` (L, S) the material it met (the renderer's order: 0
    yellow, 1 green, 2 base, 3 cavity; -1 none); ``weight`` (S,) each ray's weight in the
    quad's area mean (the bilinear parametrisation's Jacobian, mean about 1). The rays are a
    replicate's stratified samples (:meth:`Renderer.camera_ray`), the same at every length.
    """

    lengths_mm: np.ndarray
    xy_m: np.ndarray
    material: np.ndarray
    weight: np.ndarray


_SHARED: dict[Capacity, "Renderer"] = {}

#: fpar slot of the scale the kernel applies to the uploaded (unscaled) environment map
ENV_SCALE = 18


def _map_and_scale(lighting: Lighting) -> tuple[np.ndarray, float]:
    """The environment map a renderer uploads and the scale its kernels apply to it: the
    light's unscaled map and its scale when known, else its scaled map and 1 (both float32
    products, so ``map * scale`` is ``lighting.env`` texel for texel)."""
    if lighting.env_map is not None:
        return lighting.env_map, float(np.float32(lighting.env_scale))
    return lighting.env, 1.0


def _same_map(a: Lighting, b: Lighting) -> bool:
    """Whether two lights upload the same map (then its fields and sampler are kept)."""
    ma, mb = _map_and_scale(a)[0], _map_and_scale(b)[0]
    return ma is mb or np.array_equal(ma, mb)


@ti.func
def _kept(reuse: ti.i32, ray: ti.i32, n_memo: ti.i32) -> ti.i32:
    """Whether memo row ``ray`` holds what this trace would compute at the same point: every
    earlier vertex of the path kept its answer (``reuse``) and the shorter length's trace got
    that far. (Nested ifs: Taichi's ``and`` evaluates both sides.)"""
    kept = 0
    if reuse:
        if ray < n_memo:
            kept = 1
    return kept


@ti.func
def _lobe_dim(depth: ti.i32) -> ti.i32:
    """Random-number dimension (:func:`grassd.sim.tifuncs.rand01`) of the lobe choice at the
    vertex of ``depth``: 128 + depth below depth 16, then 256 + 2 depth (never one of
    :func:`_roulette_dim`'s)."""
    dim = 128 + depth
    if depth >= 16:
        dim = 256 + 2 * depth
    return dim


@ti.func
def _roulette_dim(depth: ti.i32) -> ti.i32:
    """Random-number dimension of Russian roulette at the surface of ``depth``: 144 + depth
    below depth 16, then 257 + 2 depth."""
    dim = 144 + depth
    if depth >= 16:
        dim = 257 + 2 * depth
    return dim


#: the layout arrays a scene shares with others of its display (see Renderer._upload_scene)
_LAYOUT_ARRAYS = tuple(f.name for f in fields(geometry.Primitives))
_NP_DTYPE = {ti.f32: np.float32, ti.i32: np.int32}


def _lengths_arg(lengths_mm) -> np.ndarray:
    """Green lengths (mm) as a float64 vector of 1..256 entries (what one launch holds)."""
    lengths_mm = np.asarray(lengths_mm, dtype=np.float64)
    if lengths_mm.ndim != 1 or not 1 <= len(lengths_mm) <= 256:
        raise SceneError("give 1..256 green lengths (mm)")
    return lengths_mm


def _fill(fld, arr: np.ndarray) -> None:
    """Copy ``arr`` (n, ...) into the first n entries of a field allocated at capacity, zeros
    after it."""
    full = np.zeros((fld.shape[0],) + arr.shape[1:], dtype=arr.dtype)
    full[: len(arr)] = arr
    fld.from_numpy(full)


def _cell_table(sc: SceneArrays) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The grid's items reordered so that each cell lists its blades before its rectangles,
    the index of each cell's first rectangle item, and per cell (cells, 3): the highest point of
    its fixed primitives (yellow blades, rectangles, green cavity parts), the highest root of
    its green blades (-1e30 if none) and the highest point of its rectangles (-1e30 if none),
    in metres. A ray that passes over a cell skips it; one that passes over its rectangles
    (the base top, walls and cavities, all at or below the display plane) stops after the
    blades: in the paper's pixel about half of a cell's items are rectangles, and a ray in
    the grass passes over them."""
    green = sc.blade_params[:, 3] > 0.5
    root = sc.blade_p0[:, 2].astype(np.float64)
    b = sc.rect_bounds.astype(np.float64)
    rect_top = np.where(sc.rect_axis == 2, b[:, 0], b[:, 4])
    fixed = np.concatenate([root + np.where(green, 0.0, sc.blade_params[:, 1]), rect_top])
    groot = np.concatenate([np.where(green, root, -1e30), np.full(sc.n_rects, -1e30)])
    rtop = np.concatenate([np.full(sc.n_blades, -1e30), rect_top])
    n_cells = len(sc.cell_start) - 1
    counts = np.diff(sc.cell_start)
    cell_of = np.repeat(np.arange(n_cells), counts)
    order = np.lexsort((sc.cell_items, cell_of))  # by cell, then blades (ids < nb) first
    items = sc.cell_items[order]
    n_blade_items = np.bincount(cell_of, items < sc.n_blades, minlength=n_cells)
    split = (sc.cell_start[:-1] + n_blade_items).astype(np.int32)
    out = np.full((n_cells, 3), -1e30)
    for k, value in enumerate((fixed, groot, rtop)):
        np.maximum.at(out[:, k], cell_of, value[items])
    return items.astype(np.int32), split, out.astype(np.float32)


@ti.data_oriented
class Renderer:
    """Owns the scene, environment and output fields; traces with one kernel."""

    @classmethod
    def shared(cls, capacity: Capacity | None = None) -> "Renderer":
        """The process-wide renderer for ``capacity`` (created on first use). Each Renderer
        owns its fields and compiles its own kernels, so programs should share one."""
        cap = capacity or Capacity()
        if cap not in _SHARED:
            _SHARED[cap] = cls(cap)
        return _SHARED[cap]

    def __init__(self, capacity: Capacity | None = None) -> None:
        if not is_initialised():
            raise SimError("call grassd.sim.backend.init() before creating a Renderer")
        self.cap = cap = capacity or Capacity()
        self.blade_p0 = ti.Vector.field(3, ti.f32, cap.blades)
        self.blade_a = ti.Vector.field(3, ti.f32, cap.blades)
        # (w, alpha0): a splayed green blade's rise axis at lean alpha0 + s is
        # cos(s) blade_u + sin(s) w, w = (cos(alpha0) lean_x, cos(alpha0) lean_y, -sin(alpha0))
        self.blade_lean = ti.Vector.field(4, ti.f32, cap.blades)
        self.blade_u = ti.Vector.field(3, ti.f32, cap.blades)  # rise axis without splay
        self.blade_n = ti.Vector.field(3, ti.f32, cap.blades)  # unit normal a x u
        self.blade_par = ti.Vector.field(4, ti.f32, cap.blades)  # hw, length, is_green, depth
        self.blade_mat = ti.field(ti.i32, cap.blades)
        self.rect_axis = ti.field(ti.i32, cap.rects)
        self.rect_b = ti.Vector.field(5, ti.f32, cap.rects)
        self.rect_mat = ti.field(ti.i32, cap.rects)
        self.cell_start = ti.field(ti.i32, cap.cells + 1)
        self.cell_items = ti.field(ti.i32, cap.items)
        self.cell_split = ti.field(ti.i32, cap.cells)  # first rectangle item of each cell
        # Per cell: (top of its fixed primitives, highest green root or -INF, top of its
        # rectangles or -INF) [m]; a green blade of length x reaches root + x.
        self.cell_top = ti.Vector.field(3, ti.f32, cap.cells)
        self.albedo = ti.Vector.field(3, ti.f32, 4)
        self.lengths = ti.field(ti.f32, 256)
        self.env = ti.Vector.field(3, ti.f32, cap.env_texels)
        self.env_cos = ti.field(ti.f32, cap.env_rows + 1)
        nbins = NORMAL_BINS_SIDE ** 2
        self.bin_marg = ti.field(ti.f32, nbins * (COARSE_ROWS_MAX + 1))
        self.bin_cond = ti.field(ti.f32, nbins * COARSE_ROWS_MAX * (COARSE_COLS_MAX + 1))
        self.block_cdf = ti.field(ti.f32, cap.env_texels + COARSE_ROWS_MAX * COARSE_COLS_MAX)
        self.out = ti.Vector.field(3, ti.f32, cap.paths)
        self.sums = ti.Vector.field(3, ti.f64, 256 * 64)  # per (length, replicate) of a launch
        self.traced = ti.field(ti.i64, 2)  # path traces and rays traced by the last launch
        self.skipped = ti.field(ti.i64, ())  # paths or pixels the last launch skipped (interrupt)
        # The launch (a number, :meth:`_launch`) that traced each path slot or image pixel, so
        # that a launch traced again after an interrupt traces only what it skipped; and the
        # launch whose counts ``traced`` holds.
        self.slot_launch = ti.field(ti.i32, max(cap.paths, PREVIEW_MAX * PREVIEW_MAX))
        self.counted_launch = ti.field(ti.i32, ())
        self._launches = 0
        # The word a launch reads when it has no :attr:`interrupt`: it never changes, so the
        # launch runs to its end. Of the kind an interrupt's word is (a NumPy array) where
        # interrupts work: Taichi compiles a kernel anew for each kind of array argument, so
        # the other kind would cost its first launch a compile. On a GPU, device
        # memory: there a NumPy array is copied to the device and back at every launch.
        self._no_word = (np.zeros(1, np.int32) if self.interruptible
                         else ti.ndarray(ti.i32, 1))
        self.quad = ti.Vector.field(3, ti.f32, 4)
        self.mono_index = ti.field(ti.i32, CODE_BASE ** N_SYMBOLS)  # monomial of each code
        self.term_acc = ti.Vector.field(3, ti.f64, (TERM_THREADS, N_MONOMIALS))
        self._mono_uploaded = False
        # The deep recording's fields per degree (sums, code table, threads), made on first use.
        self._deep: dict[int, tuple] = {}
        self.image = ti.Vector.field(3, ti.f32, (PREVIEW_MAX, PREVIEW_MAX))
        # Scalars: see _upload_* for the meaning of each slot.
        self.fpar = ti.field(ti.f32, 32)
        self.ipar = ti.field(ti.i32, 16)
        # Compile-time features of the uploaded scene (glossy lobe, splay): each combination
        # compiles its own kernels, so a Lambertian scene without splay (the default) runs
        # without their code, and a launch of one length without growth lengths and the memo.
        self._features = (False, False)
        self._compiled: set[tuple] = set()  # kernel variants compiled (features, launch kind)
        self._scene_key: tuple | None = None
        self._scene: SceneArrays | None = None
        self._uploaded: SceneArrays | None = None  # the scene on the fields (None: unsure)
        self.min_launch_paths: int
        self.max_launch_paths: int | None
        self.launch_paths()
        #: Stops a launch in flight when another process changes its word
        #: (:mod:`grassd.sim.interrupt`); None: launches run to their end.
        self.interrupt: Interrupt | None = None
        self._lighting: Lighting | None = None

    def launch_paths(self, fewest: int = MIN_LAUNCH_PATHS, most: int | None = None) -> None:
        """Set the camera paths a launch of :meth:`characteristic` takes (the arguments' defaults
        are the renderer's own). ``fewest`` (when there are that many): an interactive caller
        without an :attr:`interrupt` lowers it to have ``progress`` called (and stop the run
        there) more often. ``most`` (None: no limit; it wins over ``fewest``): a replicate of
        more is traced in launches of consecutive shares of its paths, so that such a
        caller's ``progress`` waits for no long launch."""
        self.min_launch_paths = fewest
        self.max_launch_paths = most

    def _ensure_compiled(self, several: tuple[bool, ...] = (True,)) -> float:
        """JIT-compile (or load from the offline cache) the kernels for the uploaded scene's
        features, for launches of several lengths (True) and/or of one (False); returns
        seconds spent."""
        t0 = time.perf_counter()
        for flag in several:
            key = (*self._features, flag)
            if key not in self._compiled:
                self._launches += 1
                self._trace_kernel(0, 0, 1, 1, 0, 1, 0, 1, ti.Vector([0.0, 0.0, 1.0]), 1.0,
                                   self._no_word, 0, self._launches, self.interruptible, *key)
                ti.sync()
                self._compiled.add(key)
        return time.perf_counter() - t0

    # ----------------------------------------------------------------------------- uploads
    def _prepare(self, display: DisplaySpec, lengths_mm: np.ndarray,
                 lighting: Lighting) -> SceneArrays:
        """Build and upload the scene and the light unless the same ones are already on the
        fields (successive calls for other viewpoints, pixels or replicates reuse them)."""
        lengths_mm = check_lengths(display.pixel, lengths_mm)
        # A scene is built conservatively for lengths up to its largest one, so it serves any
        # shorter ones too (an adaptive top-up tracing fewer lengths does not rebuild it).
        key = (display, geometry.GRID_CELL_BLADE_WIDTHS)
        longest = float(lengths_mm.max())
        if self._scene_key is None or self._scene_key[:2] != key or self._scene_key[2] < longest:
            self._scene_key = None
            scene = build_scene(display, lengths_mm)
            self._upload_scene(scene)
            self._scene, self._scene_key = scene, (*key, longest)
        if self._lighting is not lighting:
            previous, self._lighting = self._lighting, None
            # Another light with the same map (the sun moved: a time-of-day slider; another
            # lux: the map is uploaded unscaled and scaled in the kernel) keeps the uploaded
            # map and its sampler (tens of ms to rebuild); equal texels give the same
            # fields, so the images are the same bit for bit whatever ran before.
            self._upload_light(lighting, env_kept=previous is not None
                               and _same_map(previous, lighting))
            self._lighting = lighting
        return self._scene

    def _upload_scene(self, sc: SceneArrays) -> None:
        cap = self.cap
        nb, nr = sc.n_blades, sc.n_rects
        nx, ny = sc.grid_shape
        for name, need, have in (("blades", nb, cap.blades), ("rectangles", nr, cap.rects),
                                 ("grid cells", nx * ny, cap.cells),
                                 ("grid items", len(sc.cell_items), cap.items)):
            if need > have:
                raise SceneError(f"scene needs {need} {name}, the renderer holds {have}; "
                                 f"construct Renderer(Capacity(...)) larger or lower the density")

        prev = self._uploaded
        self._uploaded = None
        # A scene of the same layout (another splay or other lengths: geometry.build_scene
        # shares its read-only arrays) keeps the blades and rectangles on the fields; only the
        # grid is uploaded again, and only its used part (the kernels read no further than the
        # counts in ipar and the grid's own offsets).
        if prev is None or not all(getattr(prev, k) is getattr(sc, k) for k in _LAYOUT_ARRAYS):
            a3 = np.column_stack([sc.blade_axis, np.zeros(nb, np.float32)])
            par = sc.blade_params[:, [0, 1, 3, 4]]
            u, _ = blade_rise(sc, 0.0)  # splay-free axes (exact unless green blades splay)
            alpha0 = sc.blade_params[:, 2].astype(np.float64)
            lean = np.column_stack([np.cos(alpha0)[:, None] * sc.blade_lean, -np.sin(alpha0),
                                    alpha0])  # u's derivative in the lean, and the lean
            n = np.cross(a3.astype(np.float64), u)
            n /= np.linalg.norm(n, axis=1, keepdims=True)
            for fld, arr in ((self.blade_p0, sc.blade_p0), (self.blade_a, a3),
                             (self.blade_lean, lean), (self.blade_par, par),
                             (self.blade_u, u), (self.blade_n, n),
                             (self.blade_mat, sc.blade_params[:, 5].astype(np.int32)),
                             (self.rect_axis, sc.rect_axis), (self.rect_b, sc.rect_bounds),
                             (self.rect_mat, sc.rect_material)):
                self._put(fld, arr)
        items, split, tops = _cell_table(sc)
        for fld, arr in ((self.cell_start, sc.cell_start), (self.cell_items, items),
                         (self.cell_split, split), (self.cell_top, tops)):
            self._put(fld, arr)
        self.albedo.from_numpy(sc.albedo)
        f = self.fpar
        f[0], f[1] = float(sc.grid_origin[0]), float(sc.grid_origin[1])
        f[2] = sc.grid_cell
        f[3], f[4] = float(sc.z_range[0]), float(sc.z_range[1])
        f[5], f[6], f[7], f[8] = sc.taper_m, sc.tip_ratio, sc.splay_rad, sc.green_max_m
        f[16], f[17] = sc.specular, sc.phong_exponent
        self._features = (bool(sc.specular > 0.0), bool(sc.splay_rad > 0.0))
        f[9] = float(np.max(sc.blade_params[:, 1], initial=0.0))  # tallest fixed blade [m]
        i = self.ipar
        i[0], i[1], i[2], i[3] = nb, nr, nx, ny
        self._uploaded = sc

    def _put(self, fld, arr: np.ndarray) -> None:
        """Copy ``arr`` (n, ...) into the first n entries of ``fld`` (allocated at capacity,
        n no more than it holds), as the field's dtype; the entries after n keep what they
        held (no kernel reads them)."""
        arr = np.ascontiguousarray(arr, dtype=_NP_DTYPE[fld.dtype])
        if len(arr):
            if arr.ndim == 1:
                self._put_scalars(fld, arr, len(arr))
            else:
                self._put_vectors(fld, arr, len(arr))

    @ti.kernel
    def _put_scalars(self, fld: ti.template(), arr: ti.types.ndarray(), n: ti.i32):
        for i in range(n):
            fld[i] = arr[i]

    @ti.kernel
    def _put_vectors(self, fld: ti.template(), arr: ti.types.ndarray(), n: ti.i32):
        for i in range(n):
            for j in ti.static(range(fld.n)):
                fld[i][j] = arr[i, j]

    def _upload_light(self, lighting: Lighting, env_kept: bool = False) -> None:
        env_map, scale = _map_and_scale(lighting)
        if not env_kept:
            self._upload_env(env_map)
        self.fpar[ENV_SCALE] = scale
        sun_on = lighting.sun_direction is not None and lighting.sun_irradiance_rgb is not None
        self.ipar[6] = int(sun_on)
        if sun_on:
            sd = np.asarray(lighting.sun_direction, np.float64)
            sd = sd / np.linalg.norm(sd)
            for k in range(3):
                self.fpar[10 + k] = float(sd[k])
                self.fpar[13 + k] = float(lighting.sun_irradiance_rgb[k])

    def _upload_env(self, env: np.ndarray) -> None:
        env = np.ascontiguousarray(env, dtype=np.float32)
        h, w = env.shape[:2]
        if h * w > self.cap.env_texels or h > self.cap.env_rows:
            raise SceneError(f"environment map {w}x{h} exceeds the renderer's capacity "
                             f"({self.cap.env_texels} texels, {self.cap.env_rows} rows); "
                             f"downsample it")
        sampler = build_binned_sampler(env)
        _fill(self.env, env.reshape(-1, 3))
        _fill(self.env_cos, sampler.cos_theta_edges)
        _fill(self.bin_marg, sampler.bin_marginal.ravel())
        _fill(self.bin_cond, sampler.bin_conditional.ravel())
        _fill(self.block_cdf, sampler.block_cdf.ravel())
        _, _, cr, cc = sampler.shape
        bh, bw = sampler.block_shape
        for k, v in enumerate((h, w), start=4):
            self.ipar[k] = v
        for k, v in enumerate((cr, cc, bh, bw), start=8):
            self.ipar[k] = v

    def _put_lengths(self, lengths_mm: np.ndarray) -> None:
        """Upload green lengths (mm) to the first entries of ``self.lengths`` (m)."""
        buf = np.zeros(self.lengths.shape[0], np.float32)
        buf[: len(lengths_mm)] = np.asarray(lengths_mm) * 1e-3
        self.lengths.from_numpy(buf)

    def _put_path_settings(self, settings: RenderSettings) -> None:
        """The path's runtime settings: light samples at the first surface (``ipar[7]``) and
        the surface from which Russian roulette plays (``ipar[12]``)."""
        self.ipar[7] = settings.light_samples
        self.ipar[12] = settings.roulette_from

    # ----------------------------------------------------------------------------- kernel side
    @ti.func
    def env_radiance(self, d):
        u, v = tf.dir_to_uv(d)
        h, w = self.ipar[4], self.ipar[5]
        row = ti.min(ti.cast(v * h, ti.i32), h - 1)
        col = ti.min(ti.cast(u * w, ti.i32), w - 1)
        return self.env[row * w + col] * self.fpar[ENV_SCALE]

    @ti.func
    def row_solid_angle(self, row: ti.i32) -> ti.f32:
        return 2.0 * tf.PI / self.ipar[5] * (self.env_cos[row] - self.env_cos[row + 1])

    @ti.func
    def env_pdf(self, d, b: ti.i32) -> ti.f32:
        """Solid-angle density of :meth:`sample_env` under normal bin ``b`` in direction d
        (piecewise constant per texel, :func:`grassd.sim.env_sampler.binned_pdf`)."""
        u, v = tf.dir_to_uv(d)
        h, w = self.ipar[4], self.ipar[5]
        cr, cc, bh, bw = self.ipar[8], self.ipar[9], self.ipar[10], self.ipar[11]
        row = ti.min(ti.cast(v * h, ti.i32), h - 1)
        col = ti.min(ti.cast(u * w, ti.i32), w - 1)
        i, j = row // bh, col // bw
        k = (row % bh) * bw + col % bw
        mb = b * (cr + 1) + i
        cb = (b * cr + i) * (cc + 1) + j
        fb = (i * cc + j) * (bh * bw + 1) + k
        p_row = self.bin_marg[mb + 1] - self.bin_marg[mb]
        p_col = self.bin_cond[cb + 1] - self.bin_cond[cb]
        p_tex = self.block_cdf[fb + 1] - self.block_cdf[fb]
        return p_row * p_col * p_tex / self.row_solid_angle(row)

    @ti.func
    def sample_env(self, u1: ti.f32, u2: ti.f32, b: ti.i32):
        """Direction, solid-angle pdf and radiance of a texel sampled for normal bin ``b``
        (:mod:`grassd.sim.env_sampler`): block row from u1, block column from u2, texel in the
        block from the rest of u1, then uniform in solid angle inside the texel."""
        w = self.ipar[5]
        cr, cc, bh, bw = self.ipar[8], self.ipar[9], self.ipar[10], self.ipar[11]
        i, p_row, fv0 = tf.invert_cdf(self.bin_marg, b * (cr + 1), cr, u1)
        j, p_col, fu = tf.invert_cdf(self.bin_cond, (b * cr + i) * (cc + 1), cc, u2)
        k, p_tex, fv = tf.invert_cdf(self.block_cdf, (i * cc + j) * (bh * bw + 1), bh * bw, fv0)
        row = i * bh + k // bw
        col = j * bw + k % bw
        cos_t = self.env_cos[row] + fv * (self.env_cos[row + 1] - self.env_cos[row])
        sin_t = ti.sqrt(ti.max(0.0, 1.0 - cos_t * cos_t))
        phi = 2.0 * tf.PI * (col + fu) / w
        d = vec3(sin_t * ti.cos(phi), sin_t * ti.sin(phi), cos_t)
        pdf = p_row * p_col * p_tex / self.row_solid_angle(row)
        return d, pdf, self.env[row * w + col] * self.fpar[ENV_SCALE]

    @ti.func
    def hit_primitive(self, prim: ti.i32, o, d, x: ti.f32, x_cull: ti.f32, tmax: ti.f32,
                      zlo: ti.f32, zhi: ti.f32, turn, splay: ti.template(),
                      several: ti.template()):
        """Distance, unit geometric normal and material of primitive ``prim`` (INF if missed),
        and the green length (m) from which on a green blade missed at length ``x`` would be
        hit closer than ``tmax`` (INF for other primitives and for hits). With splay a green
        blade's plane turns with the length, so a green blade the ray comes near (one not
        culled here, as if ``x_cull`` long) gives ``x`` whether hit or missed: the ray is
        traced again at the next length.

        Rise axes and normals are precomputed per blade; only green blades with splay (their
        lean grows with the length x) are recomputed here, turned from the splay-free axis by
        the angle whose (sin, cos) is ``turn`` (the same for every blade at length x: the
        caller computes it once per ray: per blade test, that sin and cos would cost a large
        share of a splayed path's time). Its normal ``a x u`` is not unit (``a`` and ``u`` need
        not be orthogonal), and the plane test does not need it to be: :meth:`trace`
        normalises only the hit's, once per ray. ``zlo``..``zhi`` bounds the heights
        of the ray inside the current grid cell: a part lying wholly above or below it is not
        tested (a blade rises at most its length above its root, a green blade's cavity part
        spans the cavity depth below it). Green blades are culled as if ``x_cull`` (>= x)
        long, so that their growth up to that length is seen. ``splay``, ``several``:
        compile-time flags (without ``several`` the growth length means nothing)."""
        nb = self.ipar[0]
        t = tf.INF
        grow = tf.INF
        n = vec3(0.0, 0.0, 1.0)
        mat = 0
        if prim < nb:
            p0 = self.blade_p0[prim]
            a = self.blade_a[prim]
            par = self.blade_par[prim]
            u = self.blade_u[prim]
            nu = self.blade_n[prim]
            length = par[1]
            green = par[2] > 0.5
            growing = 0  # a green blade growing along a fixed axis
            splayed = 0  # a green blade whose plane turns with the length
            lean = vec4(0.0)
            if green:
                length = x
                if ti.static(splay):
                    lean = self.blade_lean[prim]
                    u = turn[1] * u + turn[0] * vec3(lean.x, lean.y, lean.z)
                    nu = a.cross(u)  # not unit: :meth:`trace` normalises the hit's normal
                    splayed = 1
                else:
                    growing = 1
            if growing:
                if zlo <= p0.z + x_cull + ZCULL and zhi >= p0.z - ZCULL:
                    t, grow = tf.hit_growing_blade(o, d, p0, a, u, nu, par[0], length,
                                                   self.fpar[5], self.fpar[6], tmax)
                    n = nu
            elif splayed:
                # Culled as if x_cull long; a blade that leans past horizontal at a length up
                # to x_cull (lean and splay may each reach 60 deg) hangs below its root, by at
                # most its length.
                below = 0.0
                if lean.w + self.fpar[7] * x_cull / self.fpar[8] > 0.5 * tf.PI:
                    below = x_cull
                if zlo <= p0.z + x_cull + ZCULL and zhi >= p0.z - below - ZCULL:
                    t1 = tf.hit_blade(o, d, p0, a, u, nu, par[0], length, self.fpar[5],
                                      self.fpar[6], tmax)
                    if t1 < tf.INF:
                        t = t1
                        n = nu
                    if ti.static(several):
                        grow = x  # a ray that comes this near may meet the turning blade
            elif zlo <= p0.z + length + ZCULL and zhi >= p0.z - ZCULL:
                t1 = tf.hit_blade(o, d, p0, a, u, nu, par[0], length, self.fpar[5],
                                  self.fpar[6], tmax)
                if t1 < tf.INF:
                    t = t1
                    n = nu
            if green and zlo <= p0.z + ZCULL and zhi >= p0.z - par[3] - ZCULL:
                # the straight part inside the cavity
                up = vec3(0.0, 0.0, 1.0)
                low = p0 - vec3(0.0, 0.0, par[3])
                n_low = vec3(a.y, -a.x, 0.0)
                t2 = tf.hit_blade(o, d, low, a, up, n_low, par[0], par[3], 1.0, 1.0,
                                  ti.min(tmax, t))
                if t2 < t:
                    t = t2
                    n = n_low
            mat = self.blade_mat[prim]
        else:
            r = prim - nb
            ax = self.rect_axis[r]
            bd = self.rect_b[r]
            z0, z1 = bd[3], bd[4]  # x-y rectangles (axis 2) lie at height bd[0]
            if ax == 2:
                z0, z1 = bd[0], bd[0]
            if zlo <= z1 + ZCULL and zhi >= z0 - ZCULL:
                t = tf.hit_rect(o, d, ax, bd[0], bd[1], bd[2], bd[3], bd[4], tmax)
            n = tf.axis_vector(ax)
            mat = self.rect_mat[r]
        return t, n, mat, grow

    @ti.func
    def trace(self, o, d, x: ti.f32, x_cull: ti.f32, tmax_in: ti.f32, any_hit: ti.i32,
              splay: ti.template(), several: ti.template()):
        """Nearest hit (or any hit, for shadows) along o + t d, t in (0, tmax_in), with green
        blades ``x`` long, and the green length from which on the answer may differ: the
        least length at which a green blade missed here would come in front of the hit (for
        any-hit queries, block the ray), INF if none (values above ``x_cull`` mean nothing:
        blades are culled as if ``x_cull`` long). Below that length the ray meets the same
        surface at the same point (the outline of a longer blade holds that of a shorter
        one), so a path whose rays all keep their answers has the same radiance. Cells and
        blades are culled for lengths up to ``x_cull`` (>= x), or up to the ray's least growth
        length so far once that is lower (less work, the same images and ray counts bit for
        bit).
        With splay a ray that comes near a green blade (which may turn into it) or is blocked
        by one (which may turn away) gets ``x``. ``splay``, ``several``
        (compile time): the scene's green blades splay; the launch traces several lengths
        (without, no growth lengths are computed and INF is returned)."""
        best_t = tmax_in
        best_n = vec3(0.0, 0.0, 1.0)
        best_m = -1
        best_g = tf.INF  # growth length the primitive of the hit reported (splay)
        grow = tf.INF
        # Green blades are culled as if x_cap long: x_cull, or this ray's least growth length
        # so far once it is lower. A green blade rises at most its length above its root, so
        # where the ray passes more than x_cap (+ ZCULL) above a blade's root the blade can
        # meet it only from a longer length on; the crossing that could lower the growth
        # length lies in a cell that lists the blade, where it is not culled. (A blade also
        # reports crossings outside the cell being walked, so culling can change growth
        # lengths that do not matter, such as one beyond the ray's hit, and so ray counts;
        # it never keeps an answer past the length where it changes.)
        x_cap = x_cull
        turn = ti.Vector([0.0, 1.0])  # (sin, cos) of the splay's lean at length x
        if ti.static(splay):
            s = self.fpar[7] * x / self.fpar[8]
            turn = ti.Vector([ti.sin(s), ti.cos(s)])
        t0 = 0.0
        t1 = tmax_in
        gx0, gy0, cell = self.fpar[0], self.fpar[1], self.fpar[2]
        nx, ny = self.ipar[2], self.ipar[3]
        lo = vec3(gx0, gy0, self.fpar[3])
        # Nothing rises above the taller of the yellow blades and the green length x.
        hi = vec3(gx0 + nx * cell, gy0 + ny * cell, ti.max(self.fpar[9], x_cull) + 1e-4)
        for k in ti.static(range(3)):  # clip to the scene's bounding box (slab method)
            if ti.abs(d[k]) < 1e-12:
                if o[k] < lo[k] or o[k] > hi[k]:
                    t1 = -1.0
            else:
                ta = (lo[k] - o[k]) / d[k]
                tb = (hi[k] - o[k]) / d[k]
                t0 = ti.max(t0, ti.min(ta, tb))
                t1 = ti.min(t1, ti.max(ta, tb))
        if t0 < t1:
            p = o + t0 * d
            ix = ti.min(ti.max(ti.cast(ti.floor((p.x - gx0) / cell), ti.i32), 0), nx - 1)
            iy = ti.min(ti.max(ti.cast(ti.floor((p.y - gy0) / cell), ti.i32), 0), ny - 1)
            sx = 1 if d.x > 0 else -1
            sy = 1 if d.y > 0 else -1
            tdx = tf.INF
            tdy = tf.INF
            tnx = tf.INF
            tny = tf.INF
            if ti.abs(d.x) > 1e-12:
                tdx = cell / ti.abs(d.x)
                tnx = (gx0 + (ix + (1 if sx > 0 else 0)) * cell - o.x) / d.x
            if ti.abs(d.y) > 1e-12:
                tdy = cell / ti.abs(d.y)
                tny = (gy0 + (iy + (1 if sy > 0 else 0)) * cell - o.y) / d.y
            done = False
            t_in = t0
            while not done:
                c = ix * ny + iy
                t_out = ti.min(tnx, tny, t1)
                za = o.z + d.z * t_in
                zb = o.z + d.z * ti.min(t_out, best_t)
                zlo, zhi = ti.min(za, zb), ti.max(za, zb)
                ct = self.cell_top[c]
                if zlo <= ti.max(ct.x, ct.y + x_cap) + ZCULL:  # else it passes over the cell
                    end = self.cell_start[c + 1]
                    if zlo > ct.z + ZCULL:  # over the cell's rectangles: its blades only
                        end = self.cell_split[c]
                    for j in range(self.cell_start[c], end):
                        prim = self.cell_items[j]
                        t, n, m, g = self.hit_primitive(prim, o, d, x, x_cap, best_t, zlo, zhi,
                                                        turn, splay, several)
                        if ti.static(several):
                            grow = ti.min(grow, g)
                            x_cap = ti.min(x_cull, ti.max(grow, x))
                        if t < best_t:
                            best_t = t
                            best_n = n
                            best_m = m
                            if ti.static(splay and several):
                                best_g = g
                            if any_hit:
                                done = True
                                break
                if best_t <= t_out or t_out >= t1:
                    done = True
                elif tnx < tny:
                    t_in = tnx
                    ix += sx
                    tnx += tdx
                    if ix < 0 or ix >= nx:
                        done = True
                else:
                    t_in = tny
                    iy += sy
                    tny += tdy
                    if iy < 0 or iy >= ny:
                        done = True
        if ti.static(splay):
            best_n = best_n.normalized()  # a turned blade's normal comes unnormalised
        if any_hit and best_m >= 0:
            grow = tf.INF  # blocked now, blocked by anything longer too ...
            if ti.static(splay and several):
                if best_g <= x:  # ... unless by a splayed green blade, which may turn away
                    grow = x
        return best_t, best_n, best_m, grow

    @ti.func
    def trace_memo(self, memo: ti.template(), n_memo: ti.i32, ray: ti.i32, reuse: ti.i32, o, d,
                   x: ti.f32, x_cull: ti.f32, any_hit: ti.i32, splay: ti.template(),
                   several: ti.template()):
        """:meth:`trace` for ray number ``ray`` of a path, taking the answer kept in ``memo``
        (a row per ray: ``MEMO_COLS``) from the path's trace at a shorter length
        when the path's earlier vertices all kept theirs (``reuse``: the ray is then the same)
        and this length is below the ray's growth length (it then meets the same surface at
        the same point: :meth:`trace`). A ray traced again leaves ``reuse`` set when it moves
        no vertex: a shadow ray (``any_hit``; its answer only weighs a light sample), or a ray
        that meets the same surface at the same distance (with splay too: a green blade turned
        into or out of the ray shows in its answer). A shadow ray outgrown by a blade that
        grows along a fixed axis is blocked without tracing; with splay it is traced. Returns
        the answer, ``reuse`` and whether the ray was traced (1) or taken from the memo (0);
        ``memo`` (by reference) holds the answer afterwards."""
        t, n, mat, g = 0.0, vec3(0.0), -1, 0.0
        kept = 0  # this ray's row of the memo: 0 none, 1 valid at this length, 2 outgrown,
        # 3 a shadow ray that got through and is now blocked by the blade that grew into it
        if ray < n_memo:
            kept = 2
            if reuse:
                if x < memo[ray, 5]:
                    kept = 1
                else:
                    if ti.static(not splay):  # a splayed blade's bound is not where it hits
                        if any_hit and memo[ray, 4] < 0.0 and x >= memo[ray, 5] + GROWN_IN:
                            kept = 3
        if kept == 1:
            t, g = memo[ray, 0], memo[ray, 5]
            n = vec3(memo[ray, 1], memo[ray, 2], memo[ray, 3])
            mat = ti.cast(memo[ray, 4], ti.i32)
        elif kept == 3:
            t, n, mat, g = memo[ray, 0], vec3(0.0, 0.0, 1.0), 0, tf.INF
            memo[ray, 4], memo[ray, 5] = 0.0, tf.INF
        else:
            t, n, mat, g = self.trace(o, d, x, x_cull, tf.INF, any_hit, splay, several)
            if not any_hit:
                same = False
                if kept == 2:
                    same = (t == memo[ray, 0] and mat == ti.cast(memo[ray, 4], ti.i32)
                            and n.x == memo[ray, 1] and n.y == memo[ray, 2]
                            and n.z == memo[ray, 3])
                if not same:
                    reuse = 0
            if ray < ti.static(MEMO_RAYS if several else 0):
                memo[ray, 0], memo[ray, 1], memo[ray, 2] = t, n.x, n.y
                memo[ray, 3], memo[ray, 4], memo[ray, 5] = n.z, ti.cast(mat, ti.f32), g
        return t, n, mat, g, reuse, 1 if kept == 0 or kept == 2 else 0

    @ti.func
    def light_and_lobe(self):
        """The uploaded sun (on, unit direction, irradiance in linear RGB) and glossy lobe
        (``ks``, Phong exponent): what every vertex of a path reads."""
        return (self.ipar[6], vec3(self.fpar[10], self.fpar[11], self.fpar[12]),
                vec3(self.fpar[13], self.fpar[14], self.fpar[15]), self.fpar[16], self.fpar[17])

    @ti.func
    def escape_weight(self, d, depth: ti.i32, pdf_bsdf: ti.f32, n_prev: ti.i32,
                      bin_prev: ti.i32) -> ti.f32:
        """MIS weight of the environment seen along a BSDF-sampled ray ``d`` (1 for a camera
        ray): balance heuristic against the previous vertex's ``n_prev`` light samples."""
        w = 1.0
        if depth > 0:
            w = tf.balance_heuristic(pdf_bsdf, n_prev * self.env_pdf(d, bin_prev))
        return w

    @ti.func
    def surface_vertex(self, o, d, t: ti.f32, n, mat: ti.i32, depth: ti.i32,
                       max_bounces: ti.i32):
        """What a path needs at the surface it met at ``o + t d``: the normal facing the ray,
        the offset point, the material's albedo, the outgoing direction, the normal's bin for
        light sampling, the Sobol' pair of this depth, its number of light samples (the
        first vertex ``ipar[7]``, later ones 1) and whether it is the last vertex (light
        sampling alone, no MIS)."""
        nn = n
        if nn.dot(d) > 0.0:
            nn = -nn
        n_nee = 1
        if depth == 0:
            n_nee = self.ipar[7]
        return (nn, o + t * d + EPS * nn, self.albedo[mat], -d,
                tf.normal_bin(nn, NORMAL_BINS_SIDE), 1 + depth * 2, n_nee,
                depth > 0 and depth == max_bounces - 1)

    @ti.func
    def radiance(self, o, d, x: ti.f32, x_cull: ti.f32, index: ti.i32, strata: ti.i32,
                 rep_key: ti.u32, key: ti.u32, max_bounces: ti.i32, memo: ti.template(),
                 n_memo: ti.i32, glossy: ti.template(), splay: ti.template(),
                 several: ti.template()):
        """Path-traced radiance along o + t d (linear Rec.709) with green blades ``x`` long,
        and the least green length from which on the path may change (meaningful up to
        ``x_cull``; with splay ``x`` once a ray comes near a green blade, whose plane turns with
        the length):
        the same random numbers give the same radiance for every length in [x, that
        length). ``memo``, ``n_memo``: the answers of the first rays of this path's trace at
        a shorter length (n_memo = 0: none); rays up to the first one whose answer changes at
        ``x`` take them instead of tracing (:meth:`trace_memo`), and light samples at a vertex
        that stays take their direction and contribution from it instead of sampling the
        environment again; this gives the same radiance to float rounding (a kept
        contribution is read back, a fresh one may be rounded in another order). Every light
        sample has a row, traced or not. ``glossy``, ``splay``: compile-time flags of the
        scene (:attr:`_features`). Returns the radiance, the growth length, the memo's row
        count for the next length, and the number of rays traced."""
        ray = 0
        rays = 0
        reuse = 0
        if ti.static(several):
            reuse = 1 if n_memo > 0 else 0
        rows = ti.static(MEMO_RAYS if several else 0)  # memo rows kept for the next length
        grow = tf.INF
        total = vec3(0.0)
        beta = vec3(1.0)
        pdf_bsdf = 0.0
        n_prev = 1
        bin_prev = 0
        sun_on, sun_dir, sun_e, ks, nexp = self.light_and_lobe()
        for depth in range(max_bounces + 1):
            # The last segment only asks whether the environment is visible (any hit).
            t, n, mat, g, reuse, fresh = self.trace_memo(
                memo, n_memo, ray, reuse, o, d, x, x_cull, 1 if depth == max_bounces else 0,
                splay, several)
            ray += 1
            rays += fresh
            grow = ti.min(grow, g)
            if mat < 0:  # escaped to the environment
                le = self.env_radiance(d)
                w = self.escape_weight(d, depth, pdf_bsdf, n_prev, bin_prev)
                total += beta * le * w
                break
            if depth == max_bounces:
                break
            if depth >= self.ipar[12]:  # Russian roulette (unbiased: survivors weigh 1 / p)
                if tf.rand01(key, _roulette_dim(depth)) >= RR_SURVIVAL:
                    break
                beta /= RR_SURVIVAL
            nn, p, alb, wo, nbin, pair, n_nee, last = self.surface_vertex(
                o, d, t, n, mat, depth, max_bounces)
            # Next-event estimation: environment, MIS against the BSDF strategy. The first vertex
            # takes ``n_nee`` light samples, later ones one. Its shadow rays decide the
            # variance: half of them are blocked by blades, in no pattern of height or
            # elevation a sampler could learn, so more samples at the first vertex pay and
            # guiding them does not; 4 + 1 was the most efficient split measured
            # (docs/renderer/measurements.md). The sun is one more shadow query (a delta
            # light: no MIS). All shadow rays share one trace call, so the kernel inlines the
            # traversal twice, not four times. Light sample j is point j of the path's n_nee in
            # the light pair's net (pair 0 is the quad position); the lobe choice is rand01.
            for j in range(n_nee + sun_on):
                wl = sun_dir
                contrib = vec3(0.0)
                kept = _kept(reuse, ray, n_memo)  # this sample is the shorter length's
                if kept:
                    wl = vec3(memo[ray, 6], memo[ray, 7], memo[ray, 8])
                    contrib = vec3(memo[ray, 9], memo[ray, 10], memo[ray, 11])
                elif j < n_nee:
                    e1, e2 = tf.owen_sobol_pair(index, strata * strata, rep_key, pair, j,
                                                n_nee)
                    wl, pdf_l, le = self.sample_env(e1, e2, nbin)
                    if pdf_l > 0.0:
                        fcos, pdf_b = tf.bsdf_eval(alb, nn, wo, wl, ks, nexp, glossy)
                        w = 1.0
                        if not last:
                            w = tf.balance_heuristic(n_nee * pdf_l, pdf_b)
                        contrib = le * fcos * (w / (pdf_l * n_nee))
                else:
                    fcos, _ = tf.bsdf_eval(alb, nn, wo, sun_dir, ks, nexp, glossy)
                    contrib = sun_e * fcos
                if nn.dot(wl) > 0.0 and contrib.max() > 0.0:
                    ts, _, ms, gs, reuse, fresh = self.trace_memo(memo, n_memo, ray, reuse,
                                                                        p, wl, x, x_cull, 1, splay,
                                                                        several)
                    rays += fresh
                    grow = ti.min(grow, gs)
                    if ms < 0:
                        total += beta * contrib
                elif ray < rows:
                    memo[ray, 5] = tf.INF  # no shadow ray: nothing to outgrow
                if ray < rows and not kept:
                    for c in ti.static(range(3)):
                        memo[ray, 6 + c], memo[ray, 9 + c] = wl[c], contrib[c]
                ray += 1
            if last:
                break
            # Continue the path by sampling the BSDF (Lambertian: throughput *= albedo).
            weight = vec3(0.0)
            if _kept(reuse, ray, n_memo):  # this bounce is the shorter length's
                d = vec3(memo[ray, 6], memo[ray, 7], memo[ray, 8])
                weight = vec3(memo[ray, 9], memo[ray, 10], memo[ray, 11])
                pdf_bsdf = memo[ray, 12]
            else:
                b1, b2 = tf.owen_sobol_pair(index, strata * strata, rep_key, pair + 1, 0, 1)
                d, weight, pdf_bsdf = tf.bsdf_sample(alb, nn, wo, ks, nexp, b1, b2,
                                                     tf.rand01(key, _lobe_dim(depth)), glossy)
                if ray < rows:
                    for c in ti.static(range(3)):
                        memo[ray, 6 + c], memo[ray, 9 + c] = d[c], weight[c]
                    memo[ray, 12] = pdf_bsdf
            n_prev = n_nee
            bin_prev = nbin
            beta *= weight
            o = p
            if beta.max() <= 0.0:
                break
        return total, grow, ti.min(ray, rows), rays

    @ti.func
    def camera_ray(self, i: ti.i32, n_samp: ti.i32, rep_key: ti.u32, eye, area: ti.f32):
        """Direction from the eye through sample ``i`` of the ``n_samp`` of a replicate on the
        measurement quad (the bilinear parametrisation of ``self.quad``), and the Jacobian of
        that parametrisation over the quad's area (the sample's weight in the area mean)."""
        su, sv = tf.owen_sobol_pair(i, n_samp, rep_key, 0, 0, 1)
        q0, q1, q2, q3 = self.quad[0], self.quad[1], self.quad[2], self.quad[3]
        q = (1 - su) * (1 - sv) * q0 + su * (1 - sv) * q1 + su * sv * q2 + (1 - su) * sv * q3
        dpu = (1 - sv) * (q1 - q0) + sv * (q2 - q3)
        dpv = (1 - su) * (q3 - q0) + su * (q2 - q1)
        return (q - eye).normalized(), dpu.cross(dpv).norm() / area

    @ti.func
    def add_terms(self, acc: ti.template(), tcode: ti.template(), tgeo: ti.template(),
                  n_terms: ti.i32, mat: ti.i32, first, second, glossy: ti.template()):
        """Add light that reflects at a vertex on material ``mat`` to the monomial sums ``acc``
        (a local (56, 3) float64 matrix, by reference): each of the path's ``n_terms`` terms
        so far (code, weight) times ``first`` (the Lambertian lobe's share, a factor of that
        material's symbol) and, if ``glossy``, times ``second`` (the glossy lobe's, a factor
        of the specular symbol)."""
        for j in range(n_terms):
            g = vec3(tgeo[j, 0], tgeo[j, 1], tgeo[j, 2])
            self.add_term(acc, tcode[j] + (1 << (2 * mat)), g * first)
            if ti.static(glossy):
                self.add_term(acc, tcode[j] + (1 << (2 * SPECULAR)), g * second)

    @ti.func
    def add_term(self, acc: ti.template(), code: ti.i32, value):
        """``acc[monomial of code] += value`` (a local matrix: no atomics)."""
        row = self.mono_index[code]
        for c in ti.static(range(3)):
            acc[row, c] += ti.cast(value[c], ti.f64)

    @ti.func
    def record_path(self, acc: ti.template(), scale: ti.f32, o, d, x: ti.f32, index: ti.i32,
                    strata: ti.i32, rep_key: ti.u32, key: ti.u32, max_bounces: ti.i32,
                    glossy: ti.template(), splay: ti.template()):
        """:meth:`radiance` of one camera path at green length ``x``, recorded as terms of the
        polynomial in the materials (:mod:`grassd.sim.albedo_terms`) into the monomial sums
        ``acc`` (by reference), each weighted by ``scale``. The path is sampled exactly as
        :meth:`radiance` samples it with the uploaded materials (the reference: same random
        numbers, lobe choices and MIS weights); every vertex's reflectance is split into its
        Lambertian lobe per unit of ``(1 - ks) albedo`` and its glossy lobe per unit of ``ks``,
        so that the path's terms hold for any albedos and ``ks``. A term is (code of its
        monomial, weight); a glossy scene doubles them at every bounce (at most 4 before the
        last vertex with ``max_bounces <= 3``). No memo: every ray is traced."""
        tcode = ti.Vector([0, 0, 0, 0, 0, 0, 0, 0], ti.i32)
        tgeo = ti.Matrix.zero(ti.f32, 8, 3)
        for c in ti.static(range(3)):
            tgeo[0, c] = scale
        n_terms = 1
        pdf_bsdf = 0.0
        n_prev = 1
        bin_prev = 0
        sun_on, sun_dir, sun_e, ks, nexp = self.light_and_lobe()
        for depth in range(max_bounces + 1):
            t, n, mat, _grow = self.trace(o, d, x, x, tf.INF,
                                          1 if depth == max_bounces else 0, splay, False)
            if mat < 0:  # escaped to the environment: the terms so far times its radiance
                le = self.env_radiance(d)
                w = self.escape_weight(d, depth, pdf_bsdf, n_prev, bin_prev)
                for j in range(n_terms):
                    g = vec3(tgeo[j, 0], tgeo[j, 1], tgeo[j, 2])
                    self.add_term(acc, tcode[j], g * le * w)
                break
            if depth == max_bounces:
                break
            if depth >= self.ipar[12]:
                if tf.rand01(key, _roulette_dim(depth)) >= RR_SURVIVAL:
                    break
                tgeo /= RR_SURVIVAL
            nn, p, alb, wo, nbin, pair, n_nee, last = self.surface_vertex(
                o, d, t, n, mat, depth, max_bounces)
            for j in range(n_nee + sun_on):
                wl = sun_dir
                light = vec3(0.0)
                if j < n_nee:
                    e1, e2 = tf.owen_sobol_pair(index, strata * strata, rep_key, pair, j, n_nee)
                    wl, pdf_l, le = self.sample_env(e1, e2, nbin)
                    if pdf_l > 0.0:
                        _fcos, pdf_b = tf.bsdf_eval(alb, nn, wo, wl, ks, nexp, glossy)
                        w = 1.0
                        if not last:
                            w = tf.balance_heuristic(n_nee * pdf_l, pdf_b)
                        light = le * (w / (pdf_l * n_nee))
                else:
                    light = sun_e
                if nn.dot(wl) > 0.0 and light.max() > 0.0:
                    _ts, _ns, ms, _gs = self.trace(p, wl, x, x, tf.INF, 1, splay, False)
                    if ms < 0:
                        first, second = tf.bsdf_lobes(nn, wo, wl, nexp, glossy)
                        self.add_terms(acc, tcode, tgeo, n_terms, mat, light * first,
                                       light * second, glossy)
            if last:
                break
            b1, b2 = tf.owen_sobol_pair(index, strata * strata, rep_key, pair + 1, 0, 1)
            d, _weight, pdf_bsdf = tf.bsdf_sample(alb, nn, wo, ks, nexp, b1, b2,
                                            tf.rand01(key, _lobe_dim(depth)), glossy)
            part_d, part_s = 1.0, 0.0  # Lambertian: f cos / pdf is the albedo itself
            if ti.static(glossy):
                part_d = 0.0
                if nn.dot(d) > 0.0 and pdf_bsdf > 0.0:
                    lobe_d, lobe_s = tf.bsdf_lobes(nn, wo, d, nexp, True)
                    part_d, part_s = lobe_d / pdf_bsdf, lobe_s / pdf_bsdf
            if part_d + part_s <= 0.0:
                break
            for j in range(n_terms):
                if ti.static(glossy):
                    tcode[n_terms + j] = tcode[j] + (1 << (2 * SPECULAR))
                    for c in ti.static(range(3)):
                        tgeo[n_terms + j, c] = tgeo[j, c] * part_s
                tcode[j] += 1 << (2 * mat)
                for c in ti.static(range(3)):
                    tgeo[j, c] *= part_d
            if ti.static(glossy):
                n_terms *= 2
            n_prev = n_nee
            bin_prev = nbin
            o = p

    @ti.func
    def add_deep(self, acc: ti.template(), table: ti.template(), th: ti.i32, code: ti.i32,
                 value):
        """``acc[th, monomial of code] += value`` (thread ``th`` owns its row: no atomics)."""
        acc[th, table[code]] += ti.cast(value, ti.f64)

    @ti.func
    def record_path_deep(self, acc: ti.template(), table: ti.template(), th: ti.i32,
                         scale: ti.f32, o, d, x: ti.f32, index: ti.i32, strata: ti.i32,
                         rep_key: ti.u32, key: ti.u32, max_bounces: ti.i32, degree: ti.i32,
                         glossy: ti.template(), splay: ti.template()):
        """:meth:`record_path` for paths of any depth, into row ``th`` of ``acc`` (monomials
        of degree 0..``degree`` by their codes ``sum(count_s * 16**s)``, ``table``): the first
        ``degree`` vertices' reflectances are symbols, later vertices multiply the terms by the
        reference's own reflectance (the tail term, :mod:`grassd.sim.albedo_terms`). A glossy
        path doubles its terms at a vertex only while they fit in ``TERM_SLOTS``; after that
        each term takes one lobe at random (in proportion to the lobes' weights, divided by
        that probability). Same paths and random numbers as :meth:`radiance`."""
        tcode = ti.Vector([0] * TERM_SLOTS, ti.i32)
        tgeo = ti.Matrix.zero(ti.f32, TERM_SLOTS, 3)
        for c in ti.static(range(3)):
            tgeo[0, c] = scale
        n_terms = 1
        pdf_bsdf = 0.0
        n_prev = 1
        bin_prev = 0
        sun_on, sun_dir, sun_e, ks, nexp = self.light_and_lobe()
        for depth in range(max_bounces + 1):
            t, n, mat, _grow = self.trace(o, d, x, x, tf.INF,
                                          1 if depth == max_bounces else 0, splay, False)
            if mat < 0:  # escaped to the environment: the terms so far times its radiance
                le = self.env_radiance(d)
                w = self.escape_weight(d, depth, pdf_bsdf, n_prev, bin_prev)
                for j in range(n_terms):
                    g = vec3(tgeo[j, 0], tgeo[j, 1], tgeo[j, 2])
                    self.add_deep(acc, table, th, tcode[j], g * le * w)
                break
            if depth == max_bounces:
                break
            if depth >= self.ipar[12]:
                if tf.rand01(key, _roulette_dim(depth)) >= RR_SURVIVAL:
                    break
                tgeo /= RR_SURVIVAL
            nn, p, alb, wo, nbin, pair, n_nee, last = self.surface_vertex(
                o, d, t, n, mat, depth, max_bounces)
            symbol = depth < degree  # this vertex's reflectance is a symbol, else the tail's
            d_ref = (1.0 - ks) * alb  # the reference's Lambertian symbol of this material
            for j in range(n_nee + sun_on):
                wl = sun_dir
                light = vec3(0.0)
                if j < n_nee:
                    e1, e2 = tf.owen_sobol_pair(index, strata * strata, rep_key, pair, j, n_nee)
                    wl, pdf_l, le = self.sample_env(e1, e2, nbin)
                    if pdf_l > 0.0:
                        _fcos, pdf_b = tf.bsdf_eval(alb, nn, wo, wl, ks, nexp, glossy)
                        w = 1.0
                        if not last:
                            w = tf.balance_heuristic(n_nee * pdf_l, pdf_b)
                        light = le * (w / (pdf_l * n_nee))
                else:
                    light = sun_e
                if nn.dot(wl) > 0.0 and light.max() > 0.0:
                    _ts, _ns, ms, _gs = self.trace(p, wl, x, x, tf.INF, 1, splay, False)
                    if ms < 0:
                        first, second = tf.bsdf_lobes(nn, wo, wl, nexp, glossy)
                        for jt in range(n_terms):
                            g = vec3(tgeo[jt, 0], tgeo[jt, 1], tgeo[jt, 2]) * light
                            if symbol:
                                self.add_deep(acc, table, th, tcode[jt] + (1 << (4 * mat)),
                                              g * first)
                                if ti.static(glossy):
                                    self.add_deep(acc, table, th,
                                                  tcode[jt] + (1 << (4 * SPECULAR)), g * second)
                            else:
                                self.add_deep(acc, table, th, tcode[jt],
                                              g * (first * d_ref + second * ks))
            if last:
                break
            b1, b2 = tf.owen_sobol_pair(index, strata * strata, rep_key, pair + 1, 0, 1)
            d, _weight, pdf_bsdf = tf.bsdf_sample(alb, nn, wo, ks, nexp, b1, b2,
                                                  tf.rand01(key, _lobe_dim(depth)), glossy)
            part_d, part_s = 1.0, 0.0  # Lambertian: f cos / pdf is the albedo itself
            if ti.static(glossy):
                part_d = 0.0
                if nn.dot(d) > 0.0 and pdf_bsdf > 0.0:
                    lobe_d, lobe_s = tf.bsdf_lobes(nn, wo, d, nexp, True)
                    part_d, part_s = lobe_d / pdf_bsdf, lobe_s / pdf_bsdf
            if part_d + part_s <= 0.0:
                break
            if not symbol:
                factor = part_d * d_ref + part_s * ks
                for jt in range(n_terms):
                    for c in ti.static(range(3)):
                        tgeo[jt, c] *= factor[c]
            elif ti.static(glossy):
                if 2 * n_terms <= TERM_SLOTS:
                    for jt in range(n_terms):
                        tcode[n_terms + jt] = tcode[jt] + (1 << (4 * SPECULAR))
                        for c in ti.static(range(3)):
                            tgeo[n_terms + jt, c] = tgeo[jt, c] * part_s
                        tcode[jt] += 1 << (4 * mat)
                        for c in ti.static(range(3)):
                            tgeo[jt, c] *= part_d
                    n_terms *= 2
                else:
                    p_s = part_s / (part_d + part_s)
                    for jt in range(n_terms):
                        if tf.rand01(key, LOBE_TERM_DIM + depth * TERM_SLOTS + jt) < p_s:
                            tcode[jt] += 1 << (4 * SPECULAR)
                            for c in ti.static(range(3)):
                                tgeo[jt, c] *= part_s / p_s
                        else:
                            tcode[jt] += 1 << (4 * mat)
                            for c in ti.static(range(3)):
                                tgeo[jt, c] *= part_d / (1.0 - p_s)
            else:
                for jt in range(n_terms):
                    tcode[jt] += 1 << (4 * mat)
            n_prev = n_nee
            bin_prev = nbin
            o = p

    @ti.kernel
    def _terms_deep_kernel(self, acc: ti.template(), table: ti.template(), n_len: ti.i32,
                           rep0: ti.i32, n_rep: ti.i32, strata: ti.i32, block: ti.i32,
                           seed: ti.u32, max_bounces: ti.i32, degree: ti.i32, eye: vec3,
                           area: ti.f32, glossy: ti.template(), splay: ti.template()):
        """Record replicates rep0 .. rep0 + n_rep - 1 at the first n_len entries of
        ``self.lengths`` (m) as monomial sums of degree 0..``degree`` (:meth:`record_path_deep`):
        thread (k, r, b) sums paths b * block .. of length k, replicate rep0 + r into row
        (k * n_rep + r) * n_blocks + b of ``acc`` (zeroed before the launch)."""
        n_samp = strata * strata
        n_blocks = (n_samp + block - 1) // block
        for b, rr, k in ti.ndrange(n_blocks, n_rep, n_len):  # lengths interleaved: balanced
            r = rep0 + rr
            rep_key = tf.replicate_key(seed, r)
            th = (k * n_rep + rr) * n_blocks + b
            for i in range(b * block, ti.min((b + 1) * block, n_samp)):
                key = tf.sample_key(seed, r, i)
                d, jac = self.camera_ray(i, n_samp, rep_key, eye, area)
                self.record_path_deep(acc, table, th, jac, eye, d, self.lengths[k], i, strata,
                                      rep_key, key, max_bounces, degree, glossy, splay)

    @ti.kernel
    def _terms_kernel(self, n_len: ti.i32, rep0: ti.i32, n_rep: ti.i32, strata: ti.i32,
                      seed: ti.u32, max_bounces: ti.i32, eye: vec3, area: ti.f32,
                      glossy: ti.template(), splay: ti.template()):
        """Record replicates rep0 .. rep0 + n_rep - 1 at the first n_len entries of
        ``self.lengths`` (m) as monomial sums: thread (k, r, b) sums paths b * TERM_BLOCK ..
        of length k, replicate rep0 + r into term_acc[(k * n_rep + r) * n_blocks + b]."""
        n_samp = strata * strata
        n_blocks = (n_samp + TERM_BLOCK - 1) // TERM_BLOCK
        for b, rr, k in ti.ndrange(n_blocks, n_rep, n_len):  # lengths interleaved: balanced
            acc = ti.Matrix.zero(ti.f64, N_MONOMIALS, 3)
            r = rep0 + rr
            rep_key = tf.replicate_key(seed, r)
            for i in range(b * TERM_BLOCK, ti.min((b + 1) * TERM_BLOCK, n_samp)):
                key = tf.sample_key(seed, r, i)
                d, jac = self.camera_ray(i, n_samp, rep_key, eye, area)
                self.record_path(acc, jac, eye, d, self.lengths[k], i, strata, rep_key, key,
                                 max_bounces, glossy, splay)
            th = (k * n_rep + rr) * n_blocks + b
            for m in range(N_MONOMIALS):
                self.term_acc[th, m] = ti.Vector([acc[m, 0], acc[m, 1], acc[m, 2]], dt=ti.f64)

    @ti.kernel
    def _trace_kernel(self, n_len: ti.i32, rep0: ti.i32, n_rep: ti.i32, strata: ti.i32,
                      i0: ti.i32, n_part: ti.i32, seed: ti.u32, max_bounces: ti.i32, eye: vec3,
                      area: ti.f32, word: ti.types.ndarray(dtype=ti.i32, ndim=1), base: ti.i32,
                      launch: ti.i32, stoppable: ti.template(), glossy: ti.template(),
                      splay: ti.template(), several: ti.template()):
        """Trace paths i0 .. i0 + n_part - 1 of replicates rep0 .. rep0 + n_rep - 1 at the
        first n_len entries of ``self.lengths`` (ascending, m). Each camera path is traced at
        the shortest length and again only at a length from which on it may change
        (:meth:`radiance`); lengths in between take its radiance, which tracing them would give
        bit for bit (same random numbers, same surfaces). Path (k, r, i) lands in
        out[(k * n_rep + r - rep0) * n_part + i - i0]. Interrupts: :meth:`_launch_begins`,
        :meth:`_slot_taken`."""
        n_samp = strata * strata
        x_cull = self.lengths[ti.max(n_len - 1, 0)]
        self._launch_begins(launch)
        for rr, ii in ti.ndrange(n_rep, n_part):
            if not self._slot_taken(rr * n_part + ii, launch, word, base, stoppable):
                continue
            r = rep0 + rr
            i = i0 + ii
            rep_key = tf.replicate_key(seed, r)
            key = tf.sample_key(seed, r, i)
            d, jac = self.camera_ray(i, n_samp, rep_key, eye, area)
            k = 0
            traces = 0
            rays = 0
            memo = ti.Matrix.zero(ti.f32, MEMO_RAYS, MEMO_COLS)
            n_memo = 0
            while k < n_len:
                traces += 1
                rad, grow, n_memo, n_rays = self.radiance(
                    eye, d, self.lengths[k], x_cull, i, strata, rep_key, key, max_bounces, memo,
                    n_memo, glossy, splay, several)
                rays += n_rays
                value = jac * rad
                self.out[(k * n_rep + rr) * n_part + ii] = value
                k += 1
                while k < n_len and self.lengths[k] < grow:
                    self.out[(k * n_rep + rr) * n_part + ii] = value
                    k += 1
            self.traced[0] += traces
            self.traced[1] += rays
            self.slot_launch[rr * n_part + ii] = launch

    @ti.kernel
    def _reduce_kernel(self, n_groups: ti.i32, n_samp: ti.i32):
        """Sum each (length, replicate) group of paths in float64, serially within the group so
        the result does not depend on thread scheduling."""
        for g in range(n_groups):
            acc = ti.Vector([0.0, 0.0, 0.0], dt=ti.f64)
            base = g * n_samp
            for i in range(n_samp):  # inner loops run serially in Taichi
                acc += ti.cast(self.out[base + i], ti.f64)
            self.sums[g] = acc

    @ti.kernel
    def _hits_kernel(self, n_len: ti.i32, strata: ti.i32, seed: ti.u32, eye: vec3,
                     area: ti.f32, splay: ti.template()):
        """The first hit of every camera ray of one replicate at the first n_len lengths:
        out[k * n + i] = (x, y, material) of ray i at length k, out[n_len * n + i] = (its
        Jacobian, 0, 0), n = strata**2."""
        n_samp = strata * strata
        rep_key = tf.replicate_key(seed, 0)
        for k, i in ti.ndrange(n_len, n_samp):
            d, jac = self.camera_ray(i, n_samp, rep_key, eye, area)
            x = self.lengths[k]
            t, _, m, _ = self.trace(eye, d, x, x, tf.INF, 0, splay, False)
            p = eye + t * d
            self.out[k * n_samp + i] = vec3(p.x, p.y, ti.cast(m, ti.f32))
            if k == 0:
                self.out[n_len * n_samp + i] = vec3(jac, 0.0, 0.0)

    @ti.kernel
    def _preview_kernel(self, width: ti.i32, spp: ti.i32, seed: ti.u32, max_bounces: ti.i32,
                        eye: vec3, forward: vec3, right: vec3, up: vec3, half: ti.f32,
                        x: ti.f32, word: ti.types.ndarray(dtype=ti.i32, ndim=1), base: ti.i32,
                        launch: ti.i32, stoppable: ti.template(), glossy: ti.template(),
                        splay: ti.template()):
        self._launch_begins(launch)
        for py, px in ti.ndrange(width, width):
            if not self._slot_taken(py * width + px, launch, word, base, stoppable):
                continue
            acc = vec3(0.0)
            rep_key = tf.replicate_key(seed, py * width + px)
            m = ti.cast(ti.ceil(ti.sqrt(ti.cast(spp, ti.f32))), ti.i32)
            for s in range(m * m):
                key = tf.sample_key(seed, py * width + px, s)
                sx = ((px + tf.rand01(key, 0)) / width * 2.0 - 1.0) * half
                sy = ((py + tf.rand01(key, 1)) / width * 2.0 - 1.0) * half
                d = (forward + sx * right - sy * up).normalized()
                memo = ti.Matrix.zero(ti.f32, MEMO_RAYS, MEMO_COLS)  # one length: nothing kept
                rad, _, _, _ = self.radiance(eye, d, x, x, s, m, rep_key, key, max_bounces,
                                             memo, 0, glossy, splay, False)
                acc += rad
            self.image[py, px] = acc / (m * m)
            self.slot_launch[py * width + px] = launch

    @ti.func
    def _launch_begins(self, launch: ti.i32):
        """A launch's serial start: no path skipped yet; the traced counts start at 0 on its
        first try only (a try after an interrupt adds the paths it traces)."""
        if self.counted_launch[None] != launch:
            self.traced[0] = 0
            self.traced[1] = 0
            self.counted_launch[None] = launch
        self.skipped[None] = 0

    @ti.func
    def _slot_taken(self, slot: ti.i32, launch: ti.i32, word: ti.template(), base: ti.i32,
                    stoppable: ti.template()) -> ti.i32:
        """Whether this try of ``launch`` traces path slot (or pixel) ``slot``: not if an
        earlier try of the launch traced it, nor, where the launch is ``stoppable``
        (:attr:`interruptible`, a compile-time flag), once ``word[0]`` differs from ``base``
        (the slot is then counted in ``skipped``: :mod:`grassd.sim.interrupt`). Elsewhere (a
        GPU) the word is not read: every thread would read one address."""
        taken = self.slot_launch[slot] != launch
        if ti.static(stoppable):
            if taken:
                # An atomic read: a plain load could be kept in a register for a task's paths.
                if ti.atomic_or(word[0], 0) != base:
                    self.skipped[None] += 1
                    taken = False
        return taken

    @property
    def interruptible(self) -> bool:
        """Whether :attr:`interrupt` can stop a launch in flight: where the kernels run on the
        CPU (:func:`~grassd.sim.backend.runs_on_host`). On a GPU a kernel would read a copy of
        the word made at launch, and the copy written back after it would undo another
        process's change, so there launches run to their end and callers check between
        them."""
        return runs_on_host()

    def _launch(self, kernel: Callable, head: tuple, tail: tuple) -> None:
        """Run ``kernel(*head, word, base, launch, stoppable, *tail)`` (a launch that skips its
        paths once ``word[0]`` differs from ``base``, where it is ``stoppable``) to its end:
        under :attr:`interrupt`, a launch that skipped paths is tried again once
        :meth:`~grassd.sim.interrupt.Interrupt.arm` allows it (or ``arm`` raises and the run
        ends), and that try traces only the paths skipped (the kernels mark each slot with
        ``launch``). Each path writes its own slot, so the numbers are those of the launch
        uninterrupted, and an interrupt that supersedes nothing (another page's input) loses no
        work."""
        self._launches += 1
        stoppable = self.interruptible
        interrupt = self.interrupt if stoppable else None
        if interrupt is None:
            kernel(*head, self._no_word, 0, self._launches, stoppable, *tail)
            return
        while True:
            kernel(*head, interrupt.word, interrupt.arm(), self._launches, stoppable, *tail)
            if int(self.skipped[None]) == 0:
                return

    # ----------------------------------------------------------------------------- public API
    def _upload_quad(self, display: DisplaySpec, scene: SceneArrays, viewpoint: Viewpoint,
                     pixel_index: int) -> tuple[np.ndarray, float]:
        """Upload the image-plane measurement quad of pixel ``pixel_index`` seen from
        ``viewpoint``; returns the eye (world m) and the quad's area."""
        centres = display.pixel_centres_m()
        if not 0 <= pixel_index < len(centres):
            raise SceneError(f"pixel_index {pixel_index} outside the display's "
                             f"{len(centres)} pixels")
        cxy = centres[pixel_index]
        corners = scene.quad_corners + np.array([cxy[0], cxy[1], 0.0])
        eye = viewpoint.eye_m(tuple(cxy))
        quad = image_quad(eye, corners)
        self.quad.from_numpy(quad.astype(np.float32))
        return eye, float(0.5 * np.linalg.norm(np.cross(quad[2] - quad[0], quad[3] - quad[1])))

    def characteristic(
        self,
        display: DisplaySpec,
        lighting: Lighting,
        viewpoint: Viewpoint,
        lengths_mm: np.ndarray,
        settings: RenderSettings | None = None,
        pixel_index: int = 0,
        progress: Callable[[int, int], None] | None = None,
    ) -> Measurement:
        """Trace the measurement quad of pixel ``pixel_index`` at every green length (mm).

        Lengths must be finite, within 0..green_max_mm, at most 256 of them. ``progress`` is
        called with (done, total) in lengths as launches finish: a launch traces all lengths
        (or as many as the path buffer holds) of a share of the replicates (or of one
        replicate's paths, :attr:`max_launch_paths`), and ``done`` is that share of the
        lengths. With one replicate the standard
        errors are NaN (no spread to estimate them from).
        """
        settings = settings or RenderSettings()
        t_start = time.perf_counter()
        lengths_mm = _lengths_arg(lengths_mm)
        scene = self._prepare(display, lengths_mm, lighting)
        eye, area = self._upload_quad(display, scene, viewpoint, pixel_index)

        m = settings.strata
        n_samp = m * m
        n_rep = settings.replicates
        if n_samp > self.cap.paths:
            raise SceneError(f"{n_samp} paths per replicate exceed the renderer's buffer of "
                             f"{self.cap.paths}; lower samples")
        # Launches: every length (ascending, so a path moves on to longer blades) of a run of
        # replicates. The buffer holds len_chunk lengths x rep_chunk replicates; a launch takes
        # at most a quarter of the replicates so progress is reported as the work goes, unless
        # that makes it smaller than min_launch_paths camera paths (:data:`MIN_LAUNCH_PATHS`).
        # The split changes no number: a path's random numbers depend
        # on its replicate, and each (length, replicate) group is summed serially (a
        # replicate split by max_launch_paths adds its shares' sums: float64 rounding).
        n = len(lengths_mm)
        order = np.argsort(lengths_mm, kind="stable")
        len_chunk = min(n, self.cap.paths // n_samp, self.sums.shape[0])
        rep_chunk = max(1, min(self.cap.paths // (len_chunk * n_samp),
                               self.sums.shape[0] // len_chunk,
                               max(-(-n_rep // 4), -(-self.min_launch_paths // n_samp))))
        # max_launch_paths caps a launch's replicates, and a replicate of more paths goes in
        # launches of a share of its paths each, their groups' sums added (in float64; one
        # share alone is the sum above).
        part = n_samp
        if self.max_launch_paths is not None:
            rep_chunk = max(1, min(rep_chunk, self.max_launch_paths // n_samp))
            if n_samp > self.max_launch_paths:  # equal shares, as few as the cap allows
                part = math.ceil(n_samp / math.ceil(n_samp / max(1, self.max_launch_paths)))
        launches = [(s, r, i) for s in range(0, n, len_chunk) for r in range(0, n_rep, rep_chunk)
                    for i in range(0, n_samp, part)]
        out = np.zeros((n, n_rep, 3), np.float64)
        self._put_path_settings(settings)
        eye_ti = ti.Vector(eye.astype(np.float32).tolist())
        t_compile = self._ensure_compiled(tuple({len(order[s: s + len_chunk]) > 1
                                                 for s, _, _ in launches}))
        t_trace0 = time.perf_counter()
        traced = rays = 0
        for done, (s, r0, i0) in enumerate(launches, start=1):
            rows = order[s: s + len_chunk]
            reps = min(rep_chunk, n_rep - r0)
            n_part = min(part, n_samp - i0)
            self._put_lengths(lengths_mm[rows])
            self._launch(self._trace_kernel,
                         (len(rows), r0, reps, m, i0, n_part, settings.seed,
                          settings.max_bounces, eye_ti, float(area)),
                         (*self._features, len(rows) > 1))
            n_groups = len(rows) * reps
            self._reduce_kernel(n_groups, n_part)
            traced += int(self.traced[0])
            rays += int(self.traced[1])
            sums = self.sums.to_numpy()[:n_groups].reshape(len(rows), reps, 3)
            out[rows, r0: r0 + reps] += sums
            if progress:
                progress(n * done // len(launches), n)
        out /= n_samp
        if not np.all(np.isfinite(out)):
            raise SimError("the renderer produced non-finite radiance; check the lighting "
                           "values (NaN/Inf texels or sun irradiance)")
        rgb = out.mean(axis=1)
        stderr = (out.std(axis=1, ddof=1) / math.sqrt(settings.replicates)
                  if settings.replicates > 1 else np.full_like(rgb, np.nan))  # no spread
        t_end = time.perf_counter()
        return Measurement(
            viewpoint=viewpoint, lengths_mm=lengths_mm, rgb_linear=rgb, rgb_stderr=stderr,
            rgb_replicates=np.transpose(out, (1, 0, 2)), samples_per_length=n_rep * n_samp,
            paths_traced=traced, rays_traced=rays,
            seconds={"compile": t_compile, "trace": t_end - t_trace0,
                     "total": t_end - t_start},
        )

    def albedo_terms(self, display: DisplaySpec, lighting: Lighting, viewpoint: Viewpoint,
                     lengths_mm: np.ndarray, settings: RenderSettings | None = None,
                     pixel_index: int = 0, glossy: bool = False,
                     degree: int | None = None) -> AlbedoTerms:
        """Trace the measurement quad at every green length (mm) as :meth:`characteristic`
        does, recording the radiance as a polynomial in the materials
        (:class:`~grassd.sim.albedo_terms.AlbedoTerms`): evaluated at the display's own
        albedos and ``specular`` it gives what :meth:`characteristic` gives with the same
        settings (to float rounding); at other albedos of a Lambertian display, what tracing
        them would give for the same paths; with a glossy lobe, an unbiased reweighting of the
        reference's paths.

        Paths are sampled with the display's materials (the reference). ``glossy`` records
        the glossy lobe even where the display's ``specular`` is 0 (its lobe is then sampled
        by the cosine lobe alone: unbiased, noisier for a sharp lobe; give the reference a
        small ``specular`` instead). With ``max_bounces <= 3`` (and ``degree`` None or 3) the
        polynomial has degree 3 (56 monomials) and holds at most
        ``TERM_THREADS / ceil(samples / TERM_BLOCK)`` lengths. Deeper paths are recorded to
        degree ``min(degree, max_bounces)`` (``degree`` None: :data:`TERM_DEGREE`), their
        further vertices as the tail term (:mod:`grassd.sim.albedo_terms`), evaluated by the
        returned terms' own ``degree``. Every length is traced in full (no reuse between
        lengths).
        """
        settings = settings or RenderSettings()
        t_start = time.perf_counter()
        if degree is not None and not 1 <= degree <= MAX_TERM_DEGREE:
            raise SceneError(f"the polynomial's degree must be in 1..{MAX_TERM_DEGREE}, "
                             f"got {degree}")
        lengths_mm = _lengths_arg(lengths_mm)
        if settings.max_bounces > MAX_DEGREE or (degree or MAX_DEGREE) != MAX_DEGREE:
            return self._albedo_terms_deep(display, lighting, viewpoint, lengths_mm, settings,
                                           pixel_index, glossy, degree, t_start)
        scene = self._prepare(display, lengths_mm, lighting)
        eye, area = self._upload_quad(display, scene, viewpoint, pixel_index)
        if not self._mono_uploaded:
            self.mono_index.from_numpy(code_table())
            self._mono_uploaded = True
        m = settings.strata
        n_samp = m * m
        n_len = len(lengths_mm)
        n_blocks = -(-n_samp // TERM_BLOCK)
        if n_len * n_blocks > TERM_THREADS:
            raise SceneError(f"{n_len} lengths x {n_samp} paths exceed the recording's "
                             f"{TERM_THREADS * TERM_BLOCK} paths per replicate; lower samples "
                             f"or lengths")
        rep_chunk = max(1, TERM_THREADS // (n_len * n_blocks))
        features = (bool(glossy or self._features[0]), self._features[1])
        self._put_lengths(lengths_mm)
        self._put_path_settings(settings)
        eye_ti = ti.Vector(eye.astype(np.float32).tolist())
        t_compile = 0.0
        if ("terms", *features) not in self._compiled:
            t0 = time.perf_counter()
            self._terms_kernel(0, 0, 1, 1, 0, 1, eye_ti, 1.0, *features)
            ti.sync()
            self._compiled.add(("terms", *features))
            t_compile = time.perf_counter() - t0
        t_trace0 = time.perf_counter()
        coeffs = np.empty((settings.replicates, n_len, N_MONOMIALS, 3))
        for r0 in range(0, settings.replicates, rep_chunk):
            reps = min(rep_chunk, settings.replicates - r0)
            self._terms_kernel(n_len, r0, reps, m, settings.seed, settings.max_bounces, eye_ti,
                               area, *features)
            acc = self.term_acc.to_numpy()[: n_len * reps * n_blocks]
            acc = acc.reshape(n_len, reps, n_blocks, N_MONOMIALS, 3).sum(axis=2) / n_samp
            coeffs[r0: r0 + reps] = np.transpose(acc, (1, 0, 2, 3))
        if not np.all(np.isfinite(coeffs)):
            raise SimError("the renderer recorded non-finite terms; check the lighting values")
        t_end = time.perf_counter()
        return AlbedoTerms(viewpoint=viewpoint, lengths_mm=lengths_mm, coefficients=coeffs,
                           glossy=features[0], samples_per_length=settings.replicates * n_samp,
                           seconds={"compile": t_compile, "trace": t_end - t_trace0,
                                    "total": t_end - t_start})

    def _deep_fields(self, degree: int) -> tuple:
        """The deep recording's sums field (threads x monomials of ``degree``), its code table
        (:func:`~grassd.sim.albedo_terms.code_table`) and its thread count, made once per
        degree."""
        if degree not in self._deep:
            m = n_monomials(degree)
            threads = max(1, DEEP_TERM_ROWS // m)
            acc = ti.Vector.field(3, ti.f64, (threads, m))
            table = ti.field(ti.i32, DEEP_CODE_BASE ** N_SYMBOLS)
            table.from_numpy(code_table(max(degree, MAX_DEGREE + 1)))
            self._deep[degree] = (acc, table, threads)
        return self._deep[degree]

    def _albedo_terms_deep(self, display: DisplaySpec, lighting: Lighting,
                           viewpoint: Viewpoint, lengths_mm: np.ndarray,
                           settings: RenderSettings, pixel_index: int, glossy: bool,
                           degree: int | None, t_start: float) -> AlbedoTerms:
        """:meth:`albedo_terms` of any depth (:meth:`_terms_deep_kernel`)."""
        deg = min(degree or TERM_DEGREE, settings.max_bounces)
        m_rows = n_monomials(max(deg, MAX_DEGREE + 1))
        scene = self._prepare(display, lengths_mm, lighting)
        eye, area = self._upload_quad(display, scene, viewpoint, pixel_index)
        acc, table, threads = self._deep_fields(max(deg, MAX_DEGREE + 1))
        m = settings.strata
        n_samp = m * m
        n_len = len(lengths_mm)
        if n_len > threads:
            raise SceneError(f"{n_len} lengths exceed the deep recording's {threads} threads; "
                             f"record fewer lengths at a time")
        block = max(DEEP_BLOCK, -(-n_samp // (threads // n_len)))
        n_blocks = -(-n_samp // block)
        rep_chunk = max(1, threads // (n_len * n_blocks))
        features = (bool(glossy or self._features[0]), self._features[1])
        self._put_lengths(lengths_mm)
        self._put_path_settings(settings)
        eye_ti = ti.Vector(eye.astype(np.float32).tolist())
        t_compile = 0.0
        if ("deep", deg, *features) not in self._compiled:
            t0 = time.perf_counter()
            self._terms_deep_kernel(acc, table, 0, 0, 1, 1, 1, 0, 1, deg, eye_ti, 1.0,
                                    *features)
            ti.sync()
            self._compiled.add(("deep", deg, *features))
            t_compile = time.perf_counter() - t0
        t_trace0 = time.perf_counter()
        coeffs = np.empty((settings.replicates, n_len, m_rows, 3))
        for r0 in range(0, settings.replicates, rep_chunk):
            reps = min(rep_chunk, settings.replicates - r0)
            acc.fill(0.0)
            self._terms_deep_kernel(acc, table, n_len, r0, reps, m, block, settings.seed,
                                    settings.max_bounces, deg, eye_ti, area, *features)
            rows = acc.to_numpy()[: n_len * reps * n_blocks]
            rows = rows.reshape(n_len, reps, n_blocks, m_rows, 3).sum(axis=2) / n_samp
            coeffs[r0: r0 + reps] = np.transpose(rows, (1, 0, 2, 3))
        if deg <= MAX_DEGREE:  # the rows of higher degree hold nothing
            coeffs = np.ascontiguousarray(coeffs[:, :, : n_monomials(deg)])
        if not np.all(np.isfinite(coeffs)):
            raise SimError("the renderer recorded non-finite terms; check the lighting values")
        t_end = time.perf_counter()
        return AlbedoTerms(viewpoint=viewpoint, lengths_mm=lengths_mm, coefficients=coeffs,
                           glossy=features[0], samples_per_length=settings.replicates * n_samp,
                           seconds={"compile": t_compile, "trace": t_end - t_trace0,
                                    "total": t_end - t_start},
                           degree=deg, tail=settings.max_bounces > deg)

    def first_hits(self, display: DisplaySpec, lighting: Lighting, viewpoint: Viewpoint,
                   lengths_mm: np.ndarray, pixel_index: int = 0, strata: int = 64,
                   seed: int = 0) -> QuadHits:
        """The first surface each of ``strata**2`` camera rays through the measurement quad of
        pixel ``pixel_index`` (seen from ``viewpoint``) meets at each green length (mm): where
        the quad's light comes from, pixel by pixel of the display (its own grass, or a
        neighbour's standing between it and the eye). ``lighting`` only completes the scene's
        upload (no light is traced)."""
        lengths_mm = _lengths_arg(lengths_mm)
        n_samp = strata * strata
        if strata < 1 or (len(lengths_mm) + 1) * n_samp > self.cap.paths:
            raise SceneError(f"{len(lengths_mm)} lengths x {n_samp} rays exceed the renderer's "
                             f"{self.cap.paths} path slots; lower strata or lengths")
        scene = self._prepare(display, lengths_mm, lighting)
        eye, area = self._upload_quad(display, scene, viewpoint, pixel_index)
        self._put_lengths(lengths_mm)
        self._hits_kernel(len(lengths_mm), strata, seed,
                          ti.Vector(eye.astype(np.float32).tolist()), area, self._features[1])
        out = self.out.to_numpy()[: (len(lengths_mm) + 1) * n_samp].astype(np.float64)
        hits = out[: len(lengths_mm) * n_samp].reshape(len(lengths_mm), n_samp, 3)
        material = hits[..., 2].round().astype(np.int32)
        xy = np.where((material >= 0)[..., None], hits[..., :2], np.nan)
        return QuadHits(lengths_mm=lengths_mm, xy_m=xy, material=material,
                        weight=out[len(lengths_mm) * n_samp:, 0])

    def preview(self, display: DisplaySpec, lighting: Lighting, viewpoint: Viewpoint,
                length_mm: float, width: int = 256, spp: int = 16,
                settings: RenderSettings | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Path-traced image (width, width, 3) of linear Rec.709 radiance of the view that
        frames pixel 0, and the (4, 2) pixel coordinates (x, y) of its measurement quad."""
        settings = settings or RenderSettings()
        if not 8 <= width <= PREVIEW_MAX or not 1 <= spp <= 4096:
            raise SceneError(f"preview width must be 8..{PREVIEW_MAX} and spp 1..4096")
        scene = self._prepare(display, np.array([length_mm], dtype=np.float64), lighting)
        cxy = display.pixel_centres_m()[0]
        corners = scene.quad_corners + np.array([cxy[0], cxy[1], 0.0])
        view = frame_quad(viewpoint.eye_m(tuple(cxy)), corners)
        self._put_path_settings(settings)
        f32 = lambda v: ti.Vector(np.asarray(v, np.float32).tolist())  # noqa: E731
        self._launch(self._preview_kernel,
                     (width, spp, settings.seed, settings.max_bounces, f32(view.eye),
                      f32(view.forward), f32(view.right), f32(view.up), view.half,
                      length_mm * 1e-3), self._features)
        img = self.image.to_numpy()[:width, :width].astype(np.float64)
        rel = image_quad(view.eye, corners) - (view.eye + view.forward)
        px = ((rel @ view.right) / view.half * 0.5 + 0.5) * width
        py = (-(rel @ view.up) / view.half * 0.5 + 0.5) * width
        return img, np.stack([px, py], axis=1)
