"""Render a directory written by ``grassd simulate export-scene`` with Mitsuba 3.

Used by the cross-check tests as an independent renderer: it reads only the exported files,
through :mod:`grassd.rigs.mitsuba_scene` (units, environment convention, quad coverage).
``llvm_ad_rgb`` when a libLLVM >= 16 is installed, else ``scalar_rgb``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from grassd.rigs.mitsuba_scene import (
    ENV_TO_WORLD,
    configure_llvm,
    mitsuba_env,
    quad_coverage,
    read_doc,
    scene_dict,
)
from grassd.sim.hdri import load_hdri


def _mi():
    import mitsuba as mi

    mi.set_variant("llvm_ad_rgb" if configure_llvm() else "scalar_rgb")  # others may switch
    return mi


def render_mean(scene_dir: Path, spp: int = 64, width: int = 128, seed: int = 0) -> np.ndarray:
    """Mean linear RGB radiance inside the measurement quad, rendered by Mitsuba on a film
    cropped to the quad, each pixel weighted by its area inside the quad."""
    mi = _mi()
    (x0, y0), weights = quad_coverage(read_doc(scene_dir), width)
    h, w = weights.shape
    scene = mi.load_dict(scene_dict(scene_dir, spp, width, crop=((x0, y0), (w, h))))
    img = np.array(mi.render(scene, seed=seed), dtype=np.float64)[..., :3]
    return np.einsum("hwc,hw->c", img, weights) / weights.sum()


def env_probe(scene_dir: Path, direction: np.ndarray) -> np.ndarray:
    """Radiance Mitsuba's envmap, fed as :func:`grassd.rigs.mitsuba_scene.scene_dict` feeds it,
    returns for a world direction."""
    mi = _mi()
    doc = read_doc(scene_dir)
    env = mitsuba_env(load_hdri(scene_dir / doc["environment"]["exr"]))
    emitter = mi.load_dict({"type": "envmap", "bitmap": mi.Bitmap(env),
                            "scale": doc["environment"]["scale"],
                            "to_world": mi.ScalarTransform4f(ENV_TO_WORLD)})
    si = mi.SurfaceInteraction3f()
    si.wi = mi.Vector3f(*(float(-c) for c in direction))
    return np.array(emitter.eval(si)).reshape(-1)[:3]
