"""Export the exact traced scene so that any other renderer can render it from a directory.

World frame: metres, z up. Files written to the output directory:

* one binary little-endian PLY triangle mesh per material (``yellow_grass.ply``, ...),
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
from pathlib import Path

import numpy as np

from grassd.sim.camera import frame_quad
from grassd.sim.geometry import MATERIAL_NAMES, build_scene, triangle_mesh
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
    albedo = {MATERIAL_NAMES[i]: {"albedo_linear": scene.albedo[i].astype(float).tolist(),
                                  "specular": scene.specular,
                                  "phong_exponent": scene.phong_exponent}
              for i in range(len(MATERIAL_NAMES))}
    write_exr(out / "env.exr", lighting.env_unscaled)

    cxy = display.pixel_centres_m()[0]
    corners = scene.quad_corners + np.array([cxy[0], cxy[1], 0.0])
    eye = viewpoint.eye_m(tuple(cxy))
    view = frame_quad(eye, corners)
    sun = None
    if lighting.sun_direction is not None:
        sun = {"direction_to_sun": np.asarray(lighting.sun_direction, float).tolist(),
               "irradiance_linear": np.asarray(lighting.sun_irradiance_rgb, float).tolist()}
    doc = {
        "units": "metres, z up, linear Rec.709",
        "camera": {"origin": eye.tolist(), "target": view.target.tolist(), "up": [0.0, 0.0, 1.0],
                   "fov_x_deg": view.fov_deg, "width": image_size, "height": image_size},
        "quad": corners.tolist(),
        "materials": albedo,
        "meshes": meshes,
        "environment": {"exr": "env.exr", "scale": float(lighting.env_scale)},
        "sun": sun,
        "max_bounces": settings.max_bounces,
        "green_length_mm": float(length_mm),
        "viewpoint": {"h_cm": viewpoint.h_cm, "d_m": viewpoint.d_m,
                      "theta_deg": viewpoint.theta_deg},
    }
    tmp = out / "scene.json.tmp"
    tmp.write_text(json.dumps(doc, indent=2))
    os.replace(tmp, out / "scene.json")
    return doc
