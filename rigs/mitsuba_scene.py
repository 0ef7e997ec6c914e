"""Mitsuba 3 as an independent reference: the scene dict of an exported directory, and the quad.

Reads only what :func:`grassd.sim.export.export_scene` writes (PLY meshes, ``env.exr``,
``scene.json``), so a disagreement points at the renderer or the export, never at shared code.
Mitsuba is a test/benchmark extra: it is imported lazily, inside the functions that need it.

Environment map. Ours is piecewise constant: texel (row i, column j) covers polar angles
``[pi i / H, pi (i + 1) / H]`` (:mod:`grassd.sim.lighting`). Mitsuba's ``envmap`` interpolates
bilinearly between sample points at columns ``u = (j + 0.5) / W`` and rows ``v = i / (H - 1)``:
its first and last rows sit ON the poles, so a map handed over as it is comes out stretched by
``H / (H - 1)`` about the horizon (half a texel at the poles; measured on the 512-row maps at
10 mm: the quad's radiance moves by 0.17 % under courtyard, within noise under forest).
:func:`mitsuba_env` resamples our map onto Mitsuba's grid ``k`` times finer: its rows at
``theta = pi r / (k H)`` take the texel they fall in, rows on a texel border the mean of the
two texels, columns repeat each texel ``k`` times. Bilinear interpolation of that grid equals
our map except within one fine step of a texel border, where it moves radiance across the
border without changing the integral over the border's neighbourhood (to second order in the
step), so the two maps agree to ``O(1 / (k H))^2``.

Units. Mitsuba offsets a secondary ray's origin by (1 + max|p|) x 8.9e-5 scene units
(:data:`MITSUBA_UNITS_PER_M`): the scene is handed over in millimetres.

Measurement. :func:`quad_mean` traces camera rays uniform over the quad through Mitsuba's
integrator: exactly our measurement. A film cropped to the quad's bounding box with every pixel
weighted by its exact area inside the quad (:func:`quad_coverage`) is what a user would render,
but a partly covered pixel carries radiance from outside the quad (the box filter averages the
whole pixel), a bias that shrinks as 1 / width (under a bright uniform sky at 512 px: +4 % in
B).

Dr.Jit's ``llvm`` variants need libLLVM >= 16 (the LLVM 15 of Debian 12 aborts at the first
render): :func:`configure_llvm` points Dr.Jit at one (Debian: ``apt-get install libllvm19``).
"""

from __future__ import annotations

import glob
import json
import os
import re
from pathlib import Path

import numpy as np

from grassd.sim.hdri import load_hdri

# Mitsuba's envmap looks up u = atan2(x, -z) / 2pi, v = acos(y) / pi in its local frame; ours is
# u = atan2(y, x) / 2pi, v = acos(z) / pi in the world frame, so local = (world_y, world_z,
# -world_x): to_world is the transpose of that matrix (a reflection, det -1).
ENV_TO_WORLD = [[0, 0, -1, 0], [1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 0, 1]]
# Mitsuba offsets a secondary ray's origin by (1 + max|p|) x 8.9e-5 scene units along the normal
# (math::RayEpsilon, spawn_ray): 89 um in a scene in metres, where blades are 1.2 mm wide and
# meet the base and each other, so 2.2 % of its shadow rays from the quad start beyond a
# neighbouring surface and see light that is not there (measured: +0.32 % in every channel
# under a uniform sky, direct light only). In millimetres the offset is 1.6 um, as ours (2 um).
MITSUBA_UNITS_PER_M = 1000.0
LLVM_MIN_MAJOR = 16  #: oldest libLLVM Dr.Jit 0.4+/Mitsuba 3.6+ renders with
ENV_REFINE = 4  #: Mitsuba map rows/columns per texel of ours (:func:`mitsuba_env`)
LLVM_GLOBS = ("/usr/lib/x86_64-linux-gnu/libLLVM*.so*", "/usr/lib/aarch64-linux-gnu/libLLVM*.so*",
              "/usr/lib/llvm-*/lib/libLLVM*.so*", "/usr/lib64/libLLVM*.so*",
              "/usr/local/lib/libLLVM*.so*")


def _llvm_major(path: str) -> int:
    """Major version in a libLLVM file name (libLLVM-19.so, libLLVM.so.19.1), or 0."""
    name = os.path.basename(path)
    m = re.search(r"libLLVM-(\d+)", name) or re.search(r"libLLVM\.so\.(\d+)", name)
    return int(m.group(1)) if m else 0


def find_libllvm() -> str | None:
    """Path of the newest libLLVM >= :data:`LLVM_MIN_MAJOR` on this machine, or None.

    ``$DRJIT_LIBLLVM_PATH`` wins when it names an existing file."""
    env = os.environ.get("DRJIT_LIBLLVM_PATH")
    if env and os.path.exists(env):
        return env
    found = [p for g in LLVM_GLOBS for p in glob.glob(g) if _llvm_major(p) >= LLVM_MIN_MAJOR]
    return max(found, key=lambda p: (_llvm_major(p), -len(p))) if found else None


def configure_llvm() -> str | None:
    """Set ``$DRJIT_LIBLLVM_PATH`` to :func:`find_libllvm` (before Mitsuba picks an llvm
    variant) and return it; None when no libLLVM >= 16 is installed."""
    path = find_libllvm()
    if path:
        os.environ["DRJIT_LIBLLVM_PATH"] = path
    return path


def mitsuba_env(env: np.ndarray, k: int = ENV_REFINE) -> np.ndarray:
    """Our (H, W, 3) piecewise-constant map -> the (k H + 1, k W, 3) map whose bilinear lookup
    in Mitsuba's lat-long convention reproduces it (module docstring). Linear radiance, any
    unit (the values are copied, not scaled)."""
    env = np.asarray(env, np.float32)
    h = env.shape[0]
    rows = np.arange(k * h + 1)
    upper = np.minimum(rows // k, h - 1)           # texel below (or at) each sample row
    lower = np.maximum((rows - 1) // k, 0)         # texel above it
    on_border = rows % k == 0
    fine = np.where(on_border[:, None, None], 0.5 * (env[lower] + env[upper]), env[upper])
    return np.ascontiguousarray(np.repeat(fine, k, axis=1), dtype=np.float32)


def read_doc(scene_dir: str | os.PathLike) -> dict:
    """The ``scene.json`` of an exported directory."""
    return json.loads((Path(scene_dir) / "scene.json").read_text())


def quad_pixels(doc: dict, width: int) -> np.ndarray:
    """(4, 2) image coordinates (x right, y down; pixel (i, j) spans [j, j + 1] x [i, i + 1]) of
    the measurement quad's corners on the exported camera's ``width`` x ``width`` film."""
    cam = doc["camera"]
    origin, target = np.array(cam["origin"]), np.array(cam["target"])
    forward = (target - origin) / np.linalg.norm(target - origin)
    right = np.cross(forward, cam["up"])
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    half = np.tan(np.radians(cam["fov_x_deg"]) / 2)
    rel = np.array(doc["quad"]) - origin
    depth = rel @ forward
    # Mitsuba's image x grows along `right`, y downwards (a mirrored quad gives 7 % different
    # colours at theta = 60 deg).
    px = ((rel @ right) / depth / half * 0.5 + 0.5) * width
    py = (-(rel @ up) / depth / half * 0.5 + 0.5) * width
    return np.stack([px, py], axis=1)


def _clip(poly: list[tuple[float, float]], axis: int, value: float, keep_below: bool):
    """Sutherland-Hodgman: the part of a polygon on one side of x_axis = value."""
    out: list[tuple[float, float]] = []
    for a, b in zip(poly, poly[1:] + poly[:1], strict=True):
        ina = (a[axis] <= value) if keep_below else (a[axis] >= value)
        inb = (b[axis] <= value) if keep_below else (b[axis] >= value)
        if ina:
            out.append(a)
        if ina != inb:
            t = (value - a[axis]) / (b[axis] - a[axis])
            out.append((a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1])))
    return out


def _area(poly: list[tuple[float, float]]) -> float:
    if len(poly) < 3:
        return 0.0
    p = np.asarray(poly)
    return 0.5 * abs(float(np.dot(p[:, 0], np.roll(p[:, 1], -1))
                           - np.dot(p[:, 1], np.roll(p[:, 0], -1))))


def quad_coverage(doc: dict, width: int) -> tuple[tuple[int, int], np.ndarray]:
    """The film crop around the quad and each of its pixels' area inside the quad (0..1).

    Returns ``((x0, y0), weights)``: the crop's offset in pixels and a (rows, cols) array of
    covered fractions, exact for the convex quad (polygon clipping on the pixels its outline
    crosses; pixels wholly inside get 1)."""
    q = quad_pixels(doc, width)
    x0, y0 = (max(0, int(np.floor(c))) for c in q.min(axis=0))
    x1, y1 = (min(width, int(np.ceil(c))) for c in q.max(axis=0))
    poly = [tuple(map(float, p)) for p in q]
    yy, xx = np.mgrid[y0:y1, x0:x1]
    # A pixel is wholly inside the convex quad when its four corners are.
    edges = np.roll(q, -1, axis=0) - q
    sign = np.sign(edges[0, 0] * edges[1, 1] - edges[0, 1] * edges[1, 0])

    def inside(px, py):
        ok = np.ones(px.shape, bool)
        for a, e in zip(q, edges, strict=True):
            ok &= sign * (e[0] * (py - a[1]) - e[1] * (px - a[0])) >= 0
        return ok

    full = (inside(xx, yy) & inside(xx + 1, yy) & inside(xx + 1, yy + 1) & inside(xx, yy + 1))
    weights = full.astype(np.float64)
    # Partly covered pixels lie on the outline: test those touched by the quad's edges.
    for (r, c) in zip(*np.nonzero(~full), strict=True):
        px, py = float(xx[r, c]), float(yy[r, c])
        part = poly
        for axis, value, below in ((0, px, False), (0, px + 1, True), (1, py, False),
                                   (1, py + 1, True)):
            part = _clip(part, axis, value, below)
            if not part:
                break
        weights[r, c] = _area(part)
    return (x0, y0), weights


def scene_dict(scene_dir: str | os.PathLike, spp: int, width: int | None = None,
               crop: tuple[tuple[int, int], tuple[int, int]] | None = None,
               env_refine: int = ENV_REFINE, units_per_m: float = MITSUBA_UNITS_PER_M) -> dict:
    """Mitsuba scene dict for an exported directory (call ``mi.set_variant`` first).

    Path tracer with ``max_depth = max_bounces + 1`` and no Russian roulette (as ours), the
    ``independent`` sampler with ``spp`` samples per pixel, a box-filtered ``width``-pixel film
    (the exported width by default), cropped to ``crop = ((x0, y0), (w, h))`` when given;
    two-sided Lambertian meshes with face normals, in millimetres (:data:`MITSUBA_UNITS_PER_M`;
    ``units_per_m=1`` keeps the exported metres); the environment resampled by
    :func:`mitsuba_env` (``env_refine`` 0 hands the exported file over as it is)."""
    import mitsuba as mi

    scene_dir = Path(scene_dir)
    doc = read_doc(scene_dir)
    cam = doc["camera"]
    w = width or cam["width"]
    film = {"type": "hdrfilm", "width": w, "height": w, "rfilter": {"type": "box"},
            "pixel_format": "rgb"}
    if crop is not None:
        (cx, cy), (cw, ch) = crop
        film.update(crop_offset_x=int(cx), crop_offset_y=int(cy), crop_width=int(cw),
                    crop_height=int(ch))
    env_file = scene_dir / doc["environment"]["exr"]
    if env_refine:
        env = {"type": "envmap", "bitmap": mi.Bitmap(mitsuba_env(load_hdri(env_file),
                                                                 env_refine))}
    else:
        env = {"type": "envmap", "filename": str(env_file)}
    env.update(scale=doc["environment"]["scale"], to_world=mi.ScalarTransform4f(ENV_TO_WORLD))
    scene = {
        "type": "scene",
        "integrator": {"type": "path", "max_depth": doc["max_bounces"] + 1,
                       "rr_depth": 1000, "hide_emitters": False},
        "sensor": {
            "type": "perspective",
            "fov": cam["fov_x_deg"],
            "fov_axis": "x",
            "to_world": mi.ScalarTransform4f().look_at(
                origin=[c * units_per_m for c in cam["origin"]],
                target=[c * units_per_m for c in cam["target"]], up=cam["up"]),
            "film": film,
            "sampler": {"type": "independent", "sample_count": spp},
        },
        "env": env,
    }
    for i, mesh in enumerate(doc["meshes"]):
        albedo = doc["materials"][mesh["material"]]["albedo_linear"]
        scene[f"mesh{i}"] = {
            "type": "ply", "filename": str(scene_dir / mesh["ply"]), "face_normals": True,
            "to_world": mi.ScalarTransform4f().scale(units_per_m),
            "bsdf": {"type": "twosided", "bsdf": {
                "type": "diffuse", "reflectance": {"type": "rgb", "value": albedo}}},
        }
    if doc["sun"]:
        scene["sun"] = {"type": "directional",
                        "direction": [-c for c in doc["sun"]["direction_to_sun"]],
                        "irradiance": {"type": "rgb", "value": doc["sun"]["irradiance_linear"]}}
    return scene


def quad_directions(doc: dict, u: np.ndarray) -> np.ndarray:
    """(n, 3) unit directions from the eye, uniform over the measurement quad's area on the image
    plane (so their mean radiance is the quad's, exactly as grassd measures it), from
    uniforms ``u`` (n, 3) in [0, 1): a triangle of the quad by area, then a point in it."""
    from grassd.sim.camera import image_quad

    eye = np.asarray(doc["camera"]["origin"], np.float64)
    q = image_quad(eye, np.asarray(doc["quad"], np.float64))
    a1 = np.linalg.norm(np.cross(q[1] - q[0], q[2] - q[0]))
    a2 = np.linalg.norm(np.cross(q[2] - q[0], q[3] - q[0]))
    first = (u[:, 0] < a1 / (a1 + a2))[:, None]
    su = np.sqrt(u[:, 1])[:, None]
    b, c = np.where(first, q[1], q[2]), np.where(first, q[2], q[3])
    p = (1 - su) * q[0] + su * (1 - u[:, 2:3]) * b + su * u[:, 2:3] * c
    d = p - eye
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def quad_mean(scene, doc: dict, n: int, seed: int, units_per_m: float = MITSUBA_UNITS_PER_M
              ) -> np.ndarray:
    """Mean linear RGB radiance over the quad from ``n`` Mitsuba paths whose camera rays are
    uniform over the quad (:func:`quad_directions`): the scene's own integrator, no film, so no
    partly covered pixels. ``seed`` picks the quad points and Mitsuba's sampler stream."""
    import mitsuba as mi

    rng = np.random.default_rng(seed)
    d = quad_directions(doc, rng.random((n, 3))).astype(np.float32)
    eye = np.asarray(doc["camera"]["origin"], np.float64) * units_per_m
    sampler = mi.load_dict({"type": "independent"})
    sampler.seed(seed, n)
    ray = mi.Ray3f(mi.Point3f(*[np.full(n, c, np.float32) for c in eye]),
                   mi.Vector3f(d[:, 0], d[:, 1], d[:, 2]))
    rgb, _, _ = scene.integrator().sample(scene, sampler, ray)
    rgb = np.asarray(rgb, np.float64)
    return (rgb.T if rgb.shape[0] == 3 and rgb.shape[-1] != 3 else rgb).mean(axis=0)
