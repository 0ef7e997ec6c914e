"""Export the exact traced scene so that any other renderer can render it from a directory.

World frame: metres, z up. Files written to the output directory:

* one binary little-endian PLY triangle mesh per material (``yellow_grass.ply``, ...; per pixel
  and material for a whole display, :func:`export_display`),
* ``env.exr``: the HDRI already rotated into the environment convention, *unscaled*
  (direction (x, y, z) -> column u = atan2(y, x) / 2pi (mod 1), row v = acos(z) / pi; u = 0 is
  the left edge, v = 0 the top row),
* ``scene.json``: camera, measurement quad, materials (linear Rec.709 albedo; ``specular`` and
  ``phong_exponent`` of the optional glossy lobe, a normalised modified Phong lobe
  ``ks (n + 2) / 2pi cos^n`` about the mirror direction over a diffuse ``(1 - ks) albedo``;
  ``specular`` 0 means purely Lambertian), meshes,
  environment scale, sun (direction towards the sun and irradiance on a plane perpendicular to
  it, linear Rec.709) and ``max_bounces`` (surface interactions per path; Mitsuba's
  ``max_depth`` = max_bounces + 1).
"""

from __future__ import annotations

import json
import os
from dataclasses import replace
from pathlib import Path

import numpy as np

from grassd.sim.camera import frame_quad
from grassd.sim.geometry import MATERIAL_NAMES, build_scene, primitive_pixels, triangle_mesh
from grassd.sim.hdri import write_exr
from grassd.sim.lighting import Lighting
from grassd.sim.scene import DisplaySpec, RenderSettings, Viewpoint


def write_ply(path: Path, vertices: np.ndarray, faces: np.ndarray) -> None:
    """Write a binary little-endian PLY (float32 x y z; uchar-count int32 vertex_indices)."""
    header = (
        "ply\nformat binary_little_endian 1.0\n"
        f"element vertex {len(vertices)}\nproperty float x\nproperty float y\nproperty float z\n"
        f"element face {len(faces)}\nproperty list uchar int vertex_indices\nend_header\n"
    ).encode("ascii")
    face_rec = np.zeros(len(faces), dtype=[("n", "u1"), ("idx", "<i4", (3,))])
    face_rec["n"] = 3
    face_rec["idx"] = faces
    tmp = path.with_suffix(".ply.tmp")
    with open(tmp, "wb") as f:
        f.write(header)
        f.write(np.asarray(vertices, "<f4").tobytes())
        f.write(face_rec.tobytes())
    os.replace(tmp, path)


def _light_doc(out: Path, lighting: Lighting) -> tuple[dict, dict | None]:
    """Write ``env.exr`` (unscaled) to ``out``; the doc's ``environment`` and ``sun`` entries."""
    write_exr(out / "env.exr", lighting.env_unscaled)
    sun = None
    if lighting.sun_direction is not None:
        sun = {"direction_to_sun": np.asarray(lighting.sun_direction, float).tolist(),
               "irradiance_linear": np.asarray(lighting.sun_irradiance_rgb, float).tolist()}
    return {"exr": "env.exr", "scale": float(lighting.env_scale)}, sun


def _camera_doc(eye: np.ndarray, corners: np.ndarray, image_size: int) -> dict:
    view = frame_quad(eye, corners)
    return {"origin": eye.tolist(), "target": view.target.tolist(), "up": [0.0, 0.0, 1.0],
            "fov_x_deg": view.fov_deg, "width": image_size, "height": image_size}


def _materials(albedo: np.ndarray, scene, prefix: str = "") -> dict:
    return {prefix + MATERIAL_NAMES[i]: {"albedo_linear": np.asarray(albedo[i], float).tolist(),
                                         "specular": scene.specular,
                                         "phong_exponent": scene.phong_exponent}
            for i in range(len(MATERIAL_NAMES))}


def _write(out: Path, doc: dict) -> dict:
    tmp = out / "scene.json.tmp"
    tmp.write_text(json.dumps(doc, indent=2))
    os.replace(tmp, out / "scene.json")
    return doc


def export_scene(out_dir: str | os.PathLike, display: DisplaySpec, lighting: Lighting,
                 viewpoint: Viewpoint, length_mm: float,
                 settings: RenderSettings | None = None, image_size: int = 512) -> dict:
    """Write the scene traced for ``viewpoint`` at green length ``length_mm`` (mm) to ``out_dir``.

    Returns the ``scene.json`` content. The camera looks from the eye at the centre of pixel 0's
    measurement quad with a square field of view that frames the quad with a 10 % margin.
    """
    settings = settings or RenderSettings()
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    scene = build_scene(display, np.array([length_mm], dtype=np.float64))
    meshes = []
    for name, (v, f) in triangle_mesh(scene, length_mm * 1e-3).items():
        write_ply(out / f"{name}.ply", v, f)
        meshes.append({"ply": f"{name}.ply", "material": name})
    environment, sun = _light_doc(out, lighting)
    cxy = display.pixel_centres_m()[0]
    corners = scene.quad_corners + np.array([cxy[0], cxy[1], 0.0])
    eye = viewpoint.eye_m(tuple(cxy))
    return _write(out, {
        "units": "metres, z up, linear Rec.709",
        "camera": _camera_doc(eye, corners, image_size),
        "quad": corners.tolist(),
        "materials": _materials(scene.albedo, scene),
        "meshes": meshes,
        "environment": environment,
        "sun": sun,
        "max_bounces": settings.max_bounces,
        "green_length_mm": float(length_mm),
        "viewpoint": {"h_cm": viewpoint.h_cm, "d_m": viewpoint.d_m,
                      "theta_deg": viewpoint.theta_deg},
    })


def export_display(out_dir: str | os.PathLike, display: DisplaySpec, lighting: Lighting,
                   eye_m: np.ndarray, lengths_mm: np.ndarray,
                   albedo_linear: np.ndarray | None = None,
                   settings: RenderSettings | None = None, image_size: int = 512) -> dict:
    """Write the whole display as traced, every pixel at its own green length and with its own
    materials, seen from one eye, to ``out_dir``.

    ``eye_m`` (3,): the camera's position (display frame, m); ``lengths_mm`` (N,): each
    row-major pixel's green length (mm); ``albedo_linear`` (N, 4, 3): each pixel's linear
    Rec.709 albedos in :data:`~grassd.sim.geometry.MATERIAL_NAMES` order (default: the
    display's pixel everywhere). Meshes and materials are named ``p{index:03d}_{material}``;
    ``scene.json`` holds every pixel's measurement quad as ``quads`` (N, 4, 3) and the camera
    frames them all with a 10 % margin. Returns the ``scene.json`` content.
    """
    settings = settings or RenderSettings()
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    n = display.rows * display.cols
    lengths = np.asarray(lengths_mm, dtype=np.float64).reshape(n)
    scene = build_scene(display, lengths)
    albedo = (np.broadcast_to(scene.albedo, (n, *scene.albedo.shape)) if albedo_linear is None
              else np.asarray(albedo_linear, dtype=np.float64).reshape(n, *scene.albedo.shape))
    blade_pixel, rect_pixel = primitive_pixels(display)
    meshes, materials, quads = [], {}, []
    centres = display.pixel_centres_m()
    for i in range(n):
        bl, re = blade_pixel == i, rect_pixel == i
        own = replace(scene, blade_p0=scene.blade_p0[bl], blade_axis=scene.blade_axis[bl],
                      blade_lean=scene.blade_lean[bl], blade_params=scene.blade_params[bl],
                      rect_axis=scene.rect_axis[re], rect_bounds=scene.rect_bounds[re],
                      rect_material=scene.rect_material[re])
        for name, (v, f) in triangle_mesh(own, lengths[i] * 1e-3).items():
            write_ply(out / f"p{i:03d}_{name}.ply", v, f)
            meshes.append({"ply": f"p{i:03d}_{name}.ply", "material": f"p{i:03d}_{name}",
                           "pixel": i})
        materials.update(_materials(albedo[i], scene, f"p{i:03d}_"))
        quads.append(scene.quad_corners + np.array([centres[i, 0], centres[i, 1], 0.0]))
    environment, sun = _light_doc(out, lighting)
    eye = np.asarray(eye_m, dtype=np.float64).reshape(3)
    return _write(out, {
        "units": "metres, z up, linear Rec.709",
        "camera": _camera_doc(eye, np.concatenate(quads), image_size),
        "quads": np.stack(quads).tolist(),
        "materials": materials,
        "meshes": meshes,
        "environment": environment,
        "sun": sun,
        "max_bounces": settings.max_bounces,
        "green_lengths_mm": lengths.tolist(),
    })
