"""``export_display``: the whole display as traced, every pixel at its own length and with its
own materials, in meshes named by pixel; read back from the PLY files it wrote."""

from __future__ import annotations

import json

import numpy as np

from grassd.sim.export import export_display, export_scene
from grassd.sim.lighting import Lighting, build_lighting
from grassd.sim.scene import DisplaySpec, PixelSpec, Viewpoint

DISPLAY = DisplaySpec(PixelSpec(), rows=2, cols=3, pitch_mm=33.5, same_layout=False)
EYE = np.array([0.1, -0.45, 0.4])


def _faces(path) -> int:
    head = path.read_bytes().split(b"end_header\n")[0].decode()
    return int(next(line.split()[-1] for line in head.splitlines()
                    if line.startswith("element face")))


def _lighting() -> Lighting:
    return build_lighting(np.full((16, 32, 3), 0.5, np.float32), 1000.0)


def test_one_length_everywhere_is_the_single_length_export_split_by_pixel(tmp_path):
    lighting = _lighting()
    whole = export_scene(tmp_path / "one", DISPLAY, lighting, Viewpoint(), 8.0)
    doc = export_display(tmp_path / "all", DISPLAY, lighting, EYE, np.full(6, 8.0))
    assert sorted({m["pixel"] for m in doc["meshes"]}) == list(range(6))
    for mesh in whole["meshes"]:
        split = [m for m in doc["meshes"] if m["material"].endswith(mesh["material"])]
        assert sum(_faces(tmp_path / "all" / m["ply"]) for m in split) == \
            _faces(tmp_path / "one" / mesh["ply"])
    assert np.asarray(doc["quads"]).shape == (6, 4, 3)
    centres = np.asarray(doc["quads"]).mean(axis=1)[:, :2]
    np.testing.assert_allclose(centres, DISPLAY.pixel_centres_m(), atol=1e-12)


def _green_faces(doc: dict, d) -> dict[int, int]:
    return {m["pixel"]: _faces(d / m["ply"]) for m in doc["meshes"]
            if m["material"].endswith("green_grass")}


def test_each_pixel_keeps_its_own_length_and_materials(tmp_path):
    lengths = np.array([0.0, 6.0, 8.0, 12.0, 16.0, 20.0])
    albedo = np.broadcast_to(DISPLAY.pixel.albedo_linear, (6, 4, 3)).copy()
    albedo[3, 1] *= 0.5  # pixel 3's green faded
    doc = export_display(tmp_path / "own", DISPLAY, _lighting(), EYE, lengths, albedo)
    saved = json.loads((tmp_path / "own" / "scene.json").read_text())
    assert saved["green_lengths_mm"] == lengths.tolist()
    green = _green_faces(doc, tmp_path / "own")
    for same in (0.0, 8.0):  # grass standing out (past the taper) or none, as if all were so
        d = tmp_path / f"{same:g}"
        alike = _green_faces(export_display(d, DISPLAY, _lighting(), EYE, np.full(6, same)), d)
        kept = [0] if same == 0.0 else list(range(1, 6))
        assert [green[i] for i in kept] == [alike[i] for i in kept]
        assert all(green[i] != alike[i] for i in range(6) if i not in kept)
    np.testing.assert_allclose(doc["materials"]["p003_green_grass"]["albedo_linear"],
                               DISPLAY.pixel.albedo_linear[1] * 0.5)
    np.testing.assert_allclose(doc["materials"]["p002_green_grass"]["albedo_linear"],
                               DISPLAY.pixel.albedo_linear[1])


def test_every_primitive_belongs_to_the_pixel_whose_cell_holds_it():
    from grassd.sim.geometry import build_scene, primitive_pixels

    scene = build_scene(DISPLAY, np.full(6, 10.0))
    blade_pixel, rect_pixel = primitive_pixels(DISPLAY)
    assert len(blade_pixel) == scene.n_blades and len(rect_pixel) == scene.n_rects
    centres = DISPLAY.pixel_centres_m()
    off = np.abs(scene.blade_p0[:, :2] - centres[blade_pixel])
    assert off.max() < DISPLAY.pitch_mm / 2 * 1e-3
    assert np.bincount(rect_pixel).tolist() == [scene.n_rects // 6] * 6
