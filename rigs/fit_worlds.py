"""Virtual captures of grass pixels whose materials are known, for ``grassd fit``'s tests and
benchmark: the real renderer draws the "real" pixel (with its own tuft layout), the virtual
camera photographs it into DNGs with a ``capture.toml`` whose ``[pixel]`` says nothing, so a fit
starts from the defaults."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from colour import delta_E

from grassd.calib.colour_spaces import rec709_to_xyz, xyz_d65_to_d50, xyz_to_lab
from grassd.daemon.offline.validate import CaptureManifest, load_manifest
from grassd.daemon.offline.virtual_capture import capture_world
from grassd.sim.light_input import LightInput
from grassd.sim.scene import PixelSpec, srgb_to_linear

LENGTHS: tuple[float, ...] = (0.0, 4.0, 8.0, 12.0, 16.0, 20.0)  #: green lengths (mm)
#: Viewpoints (h cm, d m, theta deg) to fit: steep and shallow, across and along the slits.
VIEWS: tuple[tuple[float, float, float], ...] = (
    (170.0, 2.0, 0.0), (200.0, 0.8, 90.0), (100.0, 2.5, -45.0), (250.0, 0.6, 20.0))
HELD_OUT: tuple[float, float, float] = (150.0, 1.2, 60.0)  #: judged, never fitted
PHOTO: dict[str, int] = {"width": 128, "spp": 16}  #: virtual photos: pixels, samples per pixel
ALBEDOS: tuple[str, ...] = ("yellow_srgb", "green_srgb", "base_srgb")

#: name: (the photographed pixel, HDRI of ../shared/hdri, ambient lux).
WORLDS: dict[str, tuple[PixelSpec, str, float]] = {
    # pink grass indoors (the colour the paper's future work names); blades lie as they fall
    "pink": (PixelSpec(yellow_srgb=(225.0, 200.0, 205.0), green_srgb=(235.0, 140.0, 185.0),
                       base_srgb=(215.0, 185.0, 195.0), layout_seed=101), "interior", 500.0),
    # glossy olive turf outdoors, its green blades splayed
    "olive": (PixelSpec(yellow_srgb=(170.0, 160.0, 80.0), green_srgb=(95.0, 110.0, 40.0),
                        base_srgb=(150.0, 140.0, 70.0), specular=0.06, smoothness=0.6,
                        splay_deg=7.0, layout_seed=101), "forest", 8000.0),
}


def albedo_de00(a: Any, b: Any) -> float:
    """CIEDE2000 between two 8-bit sRGB albedos, as a colour reader would compare them (D65
    sRGB to D50 CIELAB)."""
    lab = [xyz_to_lab(xyz_d65_to_d50(rec709_to_xyz(srgb_to_linear(c)))) for c in (a, b)]
    return float(delta_E(*lab))


def capture_known_pixel(root: str | Path, name: str, hdri_dir: Path, renderer: Any = None
                        ) -> tuple[CaptureManifest, Any]:
    """Photograph world ``name`` from :data:`VIEWS` and :data:`HELD_OUT` at :data:`LENGTHS`
    into ``root``; returns the manifest and the lighting (reuse it for the fit)."""
    pixel, hdri, lux = WORLDS[name]
    light = LightInput(Path(hdri_dir) / f"{hdri}.exr", lux)
    lighting = light.lighting()
    capture_world(root, light, list(VIEWS) + [HELD_OUT], list(LENGTHS), real_pixel=pixel,
                  renderer=renderer, lighting=lighting, **PHOTO)
    return load_manifest(root), lighting


def model_fields(pixel: PixelSpec) -> dict[str, Any]:
    """A photographed pixel's materials as a capture's ``[pixel]`` (its tuft layout left to
    the model)."""
    from dataclasses import asdict

    return {k: v for k, v in asdict(pixel).items() if k != "layout_seed"}


def true_fields(name: str) -> dict[str, Any]:
    """World ``name``'s materials as a capture's ``[pixel]`` (:func:`model_fields`)."""
    return model_fields(WORLDS[name][0])
