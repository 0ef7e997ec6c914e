"""Render a directory written by ``grassd simulate export-scene`` with Mitsuba 3 (scalar_rgb).

Used by the cross-check test as an independent renderer: it reads only the exported files.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from matplotlib.path import Path as PolyPath

# Mitsuba's envmap looks up u = atan2(x, -z) / 2pi, v = acos(y) / pi in its local frame.
# Our convention is u = atan2(y, x) / 2pi, v = acos(z) / pi in the world frame, so
# local = (world_y, world_z, -world_x): to_world is the transpose of that matrix.
ENV_TO_WORLD = [[0, 0, -1, 0], [1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 0, 1]]


def _mi():
    import mitsuba as mi

    if mi.variant() is None:
        mi.set_variant("scalar_rgb")
    return mi


def load_scene_dict(scene_dir: Path, spp: int, width: int | None = None) -> dict:
    mi = _mi()
    doc = json.loads((scene_dir / "scene.json").read_text())
    cam = doc["camera"]
    w = width or cam["width"]
    scene = {
        "type": "scene",
        "integrator": {"type": "path", "max_depth": doc["max_bounces"] + 1,
                       "rr_depth": 1000, "hide_emitters": False},
        "sensor": {
            "type": "perspective",
            "fov": cam["fov_x_deg"],
            "fov_axis": "x",
            "to_world": mi.ScalarTransform4f().look_at(origin=cam["origin"],
                                                        target=cam["target"], up=cam["up"]),
            "film": {"type": "hdrfilm", "width": w, "height": w, "rfilter": {"type": "box"},
                     "pixel_format": "rgb"},
            "sampler": {"type": "independent", "sample_count": spp},
        },
        "env": {"type": "envmap", "filename": str(scene_dir / doc["environment"]["exr"]),
                "scale": doc["environment"]["scale"],
                "to_world": mi.ScalarTransform4f(ENV_TO_WORLD)},
    }
    for i, mesh in enumerate(doc["meshes"]):
        albedo = doc["materials"][mesh["material"]]["albedo_linear"]
        scene[f"mesh{i}"] = {
            "type": "ply", "filename": str(scene_dir / mesh["ply"]), "face_normals": True,
            "bsdf": {"type": "twosided", "bsdf": {
                "type": "diffuse", "reflectance": {"type": "rgb", "value": albedo}}},
        }
    if doc["sun"]:
        scene["sun"] = {"type": "directional",
                        "direction": [-c for c in doc["sun"]["direction_to_sun"]],
                        "irradiance": {"type": "rgb", "value": doc["sun"]["irradiance_linear"]}}
    return scene


def quad_mask(doc: dict, width: int) -> np.ndarray:
    """Boolean (width, width) mask of pixels whose centres fall inside the projected quad."""
    cam = doc["camera"]
    origin, target = np.array(cam["origin"]), np.array(cam["target"])
    forward = (target - origin) / np.linalg.norm(target - origin)
    right = np.cross(forward, cam["up"])
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    half = np.tan(np.radians(cam["fov_x_deg"]) / 2)
    rel = np.array(doc["quad"]) - origin
    depth = rel @ forward
    # Image x grows along `right`, y downwards (checked against a viewpoint at theta = 60 deg,
    # where a mirrored mask gives 7 % different colours).
    px = ((rel @ right) / depth / half * 0.5 + 0.5) * width
    py = (-(rel @ up) / depth / half * 0.5 + 0.5) * width
    yy, xx = np.mgrid[0:width, 0:width] + 0.5
    poly = PolyPath(np.stack([px, py], axis=1))
    return poly.contains_points(np.stack([xx.ravel(), yy.ravel()], axis=1)).reshape(width, width)


def render_mean(scene_dir: Path, spp: int = 64, width: int = 128, seed: int = 0) -> np.ndarray:
    """Mean linear RGB radiance inside the measurement quad, rendered by Mitsuba."""
    mi = _mi()
    doc = json.loads((scene_dir / "scene.json").read_text())
    scene = mi.load_dict(load_scene_dict(scene_dir, spp, width))
    img = np.array(mi.render(scene, seed=seed))[..., :3]
    mask = quad_mask(doc, width)
    return img[mask].mean(axis=0)


def env_probe(scene_dir: Path, direction: np.ndarray) -> np.ndarray:
    """Radiance Mitsuba's envmap (with ENV_TO_WORLD) returns for a world direction."""
    mi = _mi()
    doc = json.loads((scene_dir / "scene.json").read_text())
    emitter = mi.load_dict({"type": "envmap", "filename": str(scene_dir / "env.exr"),
                            "scale": doc["environment"]["scale"],
                            "to_world": mi.ScalarTransform4f(ENV_TO_WORLD)})
    si = mi.SurfaceInteraction3f()
    si.wi = mi.ScalarVector3f(*(-np.asarray(direction, float)))
    return np.array(emitter.eval(si))
