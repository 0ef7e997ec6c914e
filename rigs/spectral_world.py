"""A world grassd did not render: the exported pixel in Mitsuba's spectral light, photographed.

Every other check of ``grassd validate`` / ``grassd fit`` photographs a pixel grassd's own
renderer drew through grassd's own 3x3 camera, so an error the two share cannot show. Here:

* the geometry is the pixel's exact export (:func:`grassd.sim.export.export_scene`; its tuft
  layout is the photographed pixel's ``layout_seed``, not the model's);
* Mitsuba 3 renders it in a *spectral* variant (``llvm_ad_spectral`` where Dr.Jit finds a
  libLLVM >= 16, else ``scalar_spectral``): its own path tracer with Russian roulette from
  depth :data:`RR_DEPTH` and no depth cut (:data:`MAX_DEPTH`), the sRGB albedos and the
  HDRI upsampled to smooth spectra by Mitsuba (Jakob and Hanika 2019; the map's texels times
  CIE D65), the scene dict otherwise exactly :func:`grassd.rigs.mitsuba_scene.scene_dict`'s
  (map resampling, millimetres);
* the film is Mitsuba's ``specfilm`` with the camera's spectral sensitivities as channels, so
  it stores each channel's ``integral S_c L d lambda`` (:mod:`grassd.rigs.spectral_camera`), plus
  the CIE observer's three for the truth;
* a ColorChecker (N. Ohta's 24 measured reflectance spectra, 80 % of each cell, on a 3 %
  body) lies flat under the same map, seen from straight above, and a perfect white card
  sets the exposure of every photo, as a photographer sets it;
* the chart's reference values are its spectra's own CIELAB (CIE 1931 2 degree, D50), written
  as a chart CSV (:func:`write_chart_csv`), so the checker's residual is the camera's and the
  transport's, not a misprint's.

:func:`photograph_world` writes one capture directory per camera (``capture.toml``,
``checker.dng``, one DNG per viewpoint and length, ``env.exr``, ``chart.csv``,
``camera.csv`` with the camera's spectral sensitivities, which ``capture.toml`` names as
``camera_sensitivities`` (so validate and fit read the photos through the camera's own
response; give the manifest ``sensitivities=None`` to read them through the checker's
correction instead), ``true_pixel.toml`` with the photographed materials as a
``[display.pixel]`` table for ``grassd validate --pixel``, and ``truth.json`` with the CIE
XYZ of every quad) that ``grassd validate`` and ``grassd fit`` read as they read a site's
photos.

Glossy lobes (``specular`` > 0) have no Mitsuba counterpart of grassd's normalised modified
Phong lobe, so the rig refuses them; its materials are Lambertian.
"""

from __future__ import annotations

import json
import shutil
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from grassd.calib.camera_response import CameraSensitivities, write_sensitivities
from grassd.calib.colour_spaces import WHITE_D50_XY
from grassd.rigs.mitsuba_scene import (
    configure_llvm,
    quad_coverage,
    quad_pixels,
    read_doc,
    scene_dict,
)
from grassd.rigs.spectral_camera import (
    SpectralCamera,
    checker_reflectances,
    cie_observer,
    integrate,
    irregular_spectrum,
    resample,
)
from grassd.sim.export import export_scene
from grassd.sim.hdri import downsample, load_hdri, write_exr
from grassd.sim.light_input import LightInput
from grassd.sim.scene import DisplaySpec, PixelSpec, Viewpoint

MAX_DEPTH = -1  #: Mitsuba ``max_depth``: -1, no cut (Russian roulette alone, as grassd's)
#: Mitsuba map rows/columns per texel of the capture's map (:func:`grassd.rigs.mitsuba_scene.
#: mitsuba_env`). Mitsuba's spectral envmap interpolates its texels' upsampling coefficients,
#: not their spectra, between the refined map's rows; the finer map keeps that blend to a
#: sixteenth of each texel, so each texel of the capture's map has its own smooth spectrum.
ENV_REFINE = 16
RR_DEPTH = 5  #: Mitsuba's default depth at which Russian roulette starts
CHART_CELL_MM = 40.0  #: chart cell pitch
CHART_FILL = 0.8  #: patch side / cell side (as grassd's analytic checker photo)
CHART_BODY = 0.03  #: reflectance of the chart body between the patches
CHECKER_WIDTH = 256  #: checker photo width = height (pixels)
XYZ = "xyz_"  #: film channel prefix of the CIE observer
SENSITIVITIES_CSV = "camera.csv"  #: the camera's sensitivities, as capture.toml names them


class SpectralWorldError(RuntimeError):
    """The spectral world cannot be built or rendered as asked; the message says how to fix."""


def set_spectral_variant() -> str:
    """Select and return Mitsuba's spectral variant: ``llvm_ad_spectral`` when Dr.Jit finds a
    libLLVM >= 16 (:func:`grassd.rigs.mitsuba_scene.configure_llvm`), else ``scalar_spectral``."""
    import mitsuba as mi

    variant = "llvm_ad_spectral" if configure_llvm() else "scalar_spectral"
    if variant not in mi.variants():
        raise SpectralWorldError(f"this Mitsuba has no {variant} variant; install the wheel "
                                 "from PyPI (pip install mitsuba)")
    mi.set_variant(variant)
    return variant


def film_channels(cameras: Sequence[SpectralCamera]) -> dict[str, dict]:
    """specfilm channels: ``c{i}_r/g/b`` per camera and ``xyz_x/y/z`` for the CIE observer."""
    channels: dict[str, dict] = {}
    for i, cam in enumerate(cameras):
        channels.update(cam.film_channels(f"c{i}_"))
    cmf = cie_observer()
    channels.update({f"{XYZ}{c}": irregular_spectrum(cmf[:, k]) for k, c in enumerate("xyz")})
    return channels


def _specfilm(width: int, cameras: Sequence[SpectralCamera]) -> dict:
    return {"type": "specfilm", "width": width, "height": width, "rfilter": {"type": "box"},
            **film_channels(cameras)}


def _integrator(max_depth: int, rr_depth: int) -> dict:
    return {"type": "path", "max_depth": int(max_depth), "rr_depth": int(rr_depth),
            "hide_emitters": False}


def pixel_scene_dict(scene_dir: str | Path, cameras: Sequence[SpectralCamera], spp: int,
                     width: int, max_depth: int = MAX_DEPTH, rr_depth: int = RR_DEPTH) -> dict:
    """Mitsuba scene dict of an exported directory for a spectral variant (set it first):
    :func:`grassd.rigs.mitsuba_scene.scene_dict` with the camera's ``specfilm`` and a path
    tracer of depth ``max_depth`` with Russian roulette from ``rr_depth``. Its ``rgb``
    reflectances and map are upsampled by Mitsuba itself. Refuses glossy materials."""
    doc = read_doc(scene_dir)
    glossy = [k for k, m in doc["materials"].items() if m.get("specular", 0.0) > 0]
    if glossy:
        raise SpectralWorldError(f"materials {', '.join(glossy)} have a glossy lobe; the "
                                 "spectral world renders Lambertian pixels only (specular = 0)")
    d = scene_dict(scene_dir, spp, width, env_refine=ENV_REFINE)
    d["sensor"]["film"] = _specfilm(width, cameras)
    d["integrator"] = _integrator(max_depth, rr_depth)
    return d


def _channels(scene, img) -> dict[str, NDArray[np.float64]]:
    """The rendered film's channels by name, (H, W) each, negatives (none expected) at 0: the
    image's channels follow the film bitmap's fields, in the order the film was given them."""
    names = [f.name for f in scene.sensors()[0].film().bitmap().struct_()]
    arr = np.clip(np.array(img, np.float64), 0.0, None)
    if arr.shape[-1] != len(names):
        raise SpectralWorldError(f"Mitsuba returned {arr.shape[-1]} channels for {names}")
    return {n: arr[..., i] for i, n in enumerate(names)}


def _split(ch: dict, n: int) -> tuple[list[NDArray[np.float64]], NDArray[np.float64]]:
    cams = [np.stack([ch[f"c{i}_{c}"] for c in "rgb"], -1) for i in range(n)]
    return cams, np.stack([ch[f"{XYZ}{c}"] for c in "xyz"], -1)


def render_pixel(scene_dir: str | Path, cameras: Sequence[SpectralCamera], spp: int,
                 width: int, seed: int = 0, max_depth: int = MAX_DEPTH,
                 rr_depth: int = RR_DEPTH) -> tuple[list[NDArray[np.float64]],
                                                    NDArray[np.float64]]:
    """Render an exported directory (a pixel's or a whole display's) spectrally on a
    ``width``-pixel square film of its camera:
    each camera's raw RGB image (H, W, 3) and the CIE XYZ image (H, W, 3), in Mitsuba's
    radiance units times nm (a map texel of RGB (1, 1, 1) emits CIE D65 / 100)."""
    import mitsuba as mi

    set_spectral_variant()
    scene = mi.load_dict(pixel_scene_dict(scene_dir, cameras, spp, width, max_depth, rr_depth))
    img = mi.render(scene, seed=seed)
    return _split(_channels(scene, img), len(cameras))


def observed_quads(work_dir: str | Path, display: DisplaySpec, lighting,
                   viewpoint: Viewpoint, lengths_mm: Sequence[float], spp: int = 256,
                   width: int = 64) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """What the CIE observer sees of ``display``'s measurement quad from ``viewpoint`` at each
    green length (mm), rendered spectrally (:func:`render_pixel`; each scene exported under
    ``work_dir``), and of a perfect white card lying flat under the same light: the quads'
    CIE XYZ (n, 3) and the card's (3,), in Mitsuba's units (their ratio is what a white
    balance reads)."""
    quads = []
    for k, x in enumerate(lengths_mm):
        sd = Path(work_dir) / (f"{viewpoint.h_cm:g}_{viewpoint.d_m:g}_{viewpoint.theta_deg:g}_"
                               f"{float(x):05.2f}mm")
        doc = export_scene(sd, display, lighting, viewpoint, float(x))
        _, xyz = render_pixel(sd, [], spp, width, seed=k)
        (x0, y0), w = quad_coverage(doc, width)
        quads.append(np.einsum("hwc,hw->c", xyz[y0:y0 + w.shape[0], x0:x0 + w.shape[1]], w)
                     / w.sum())
    _, white = render_white_card(sd, [], spp=4 * spp)
    return np.stack(quads), white


def _light_only(scene_dir: str | Path, spp: int) -> dict:
    """scene_dict's light (map, sun) without the pixel's meshes."""
    d = scene_dict(scene_dir, spp, 2, env_refine=ENV_REFINE)
    for k in [k for k in d if k.startswith("mesh")]:
        del d[k]
    return d


def _top_down(width: int, cameras: Sequence[SpectralCamera], spp: int, half_mm: float,
              height_mm: float = 2000.0) -> tuple[dict, dict]:
    """A perspective sensor at ``height_mm`` above the origin looking straight down (image up
    = +y, right = +x) framing +-``half_mm``, and its camera in scene.json's terms."""
    import mitsuba as mi

    fov = float(np.degrees(2 * np.arctan(half_mm / height_mm)))
    cam = {"origin": [0.0, 0.0, height_mm], "target": [0.0, 0.0, 0.0], "up": [0.0, 1.0, 0.0],
           "fov_x_deg": fov}
    sensor = {"type": "perspective", "fov": fov, "fov_axis": "x",
              "to_world": mi.ScalarTransform4f().look_at(origin=cam["origin"],
                                                         target=cam["target"], up=cam["up"]),
              "film": _specfilm(width, cameras),
              "sampler": {"type": "independent", "sample_count": int(spp)}}
    return sensor, cam


def _rectangle(cx: float, cy: float, z: float, w: float, h: float, reflectance: dict) -> dict:
    import mitsuba as mi

    return {"type": "rectangle",
            "to_world": mi.ScalarTransform4f().translate([cx, cy, z]).scale([w / 2, h / 2, 1]),
            "bsdf": {"type": "diffuse", "reflectance": reflectance}}


def render_white_card(scene_dir: str | Path, cameras: Sequence[SpectralCamera],
                      spp: int = 256, seed: int = 0) -> tuple[list[NDArray[np.float64]],
                                                              NDArray[np.float64]]:
    """Raw RGB (3,) per camera and CIE XYZ (3,) of a perfect white Lambertian card lying flat
    under the exported directory's light (its map and sun; the pixel's meshes left out)."""
    import mitsuba as mi

    set_spectral_variant()
    d = _light_only(scene_dir, spp)
    d["sensor"], _ = _top_down(16, cameras, spp, 10.0)
    d["integrator"] = _integrator(2, 1000)
    d["card"] = _rectangle(0.0, 0.0, 0.0, 100.0, 100.0, {"type": "uniform", "value": 1.0})
    scene = mi.load_dict(d)
    img = mi.render(scene, seed=seed)
    cams, xyz = _split(_channels(scene, img), len(cameras))
    return [c.mean((0, 1)) for c in cams], xyz.mean((0, 1))


def chart_corners_mm() -> NDArray[np.float64]:
    """(4, 3) world corners (mm) of the chart's patch area, TL, TR, BR, BL as seen from above."""
    hw, hh = 3 * CHART_CELL_MM, 2 * CHART_CELL_MM
    return np.array([[-hw, hh, 0.0], [hw, hh, 0.0], [hw, -hh, 0.0], [-hw, -hh, 0.0]])


def render_checker(scene_dir: str | Path, cameras: Sequence[SpectralCamera],
                   width: int = CHECKER_WIDTH, spp: int = 16, seed: int = 0
                   ) -> tuple[list[NDArray[np.float64]], NDArray[np.float64],
                              NDArray[np.float64]]:
    """The checker photographed from above under the exported directory's light: raw RGB
    images per camera (width, width, 3), the CIE XYZ image, and the (4, 2) image corners of
    the patch area (TL, TR, BR, BL; x right, y down, pixels)."""
    import mitsuba as mi

    set_spectral_variant()
    _, refl = checker_reflectances()
    half = 3 * CHART_CELL_MM * 1.25
    d = _light_only(scene_dir, spp)
    d["sensor"], cam = _top_down(width, cameras, spp, half)
    d["integrator"] = _integrator(2, 1000)
    d["body"] = _rectangle(0.0, 0.0, 0.0, 2 * half, 2 * half,
                           {"type": "uniform", "value": CHART_BODY})
    side = CHART_FILL * CHART_CELL_MM
    for k, r in enumerate(refl):
        row, col = divmod(k, 6)
        d[f"patch{k:02d}"] = _rectangle(-3 * CHART_CELL_MM + CHART_CELL_MM * (col + 0.5),
                                        2 * CHART_CELL_MM - CHART_CELL_MM * (row + 0.5), 0.2,
                                        side, side, irregular_spectrum(r))
    scene = mi.load_dict(d)
    img = mi.render(scene, seed=seed)
    cams, xyz = _split(_channels(scene, img), len(cameras))
    corners = quad_pixels({"camera": cam, "quad": chart_corners_mm().tolist()}, width)
    return cams, xyz, corners


def chart_lab() -> tuple[tuple[str, ...], NDArray[np.float64]]:
    """Names and (24, 3) CIELAB (D50 white, CIE 1931 2 degree observer, CIE D50 light) of the
    checker spectra the rig photographs: the chart's own reference values."""
    import colour

    names, refl = checker_reflectances()
    d50 = colour.SDS_ILLUMINANTS["D50"]
    e = resample(d50.wavelengths, d50.values)
    cmf = cie_observer()
    xyz = integrate(refl * e, cmf) / integrate(e, cmf)[1]
    return names, colour.XYZ_to_Lab(xyz, WHITE_D50_XY)


def write_chart_csv(path: str | Path) -> Path:
    """Write :func:`chart_lab` as a grassd chart CSV (``name,L,a,b``)."""
    names, lab = chart_lab()
    lines = ["# ColorChecker N Ohta spectra (colour-science), CIELAB D50, CIE 1931 2 deg"]
    lines += [f"{n.replace(',', ' ')},{v[0]:.4f},{v[1]:.4f},{v[2]:.4f}"
              for n, v in zip(names, lab, strict=True)]
    p = Path(path)
    p.write_text("\n".join(lines) + "\n")
    return p


def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, int):
        return str(v)
    return repr(float(v))


def pixel_toml(pixel: PixelSpec) -> str:
    """A ``[display.pixel]`` table of the pixel's fields, its layout seed left out (the model
    draws its own tufts), as ``grassd validate --pixel`` reads it."""
    fields_ = {k: v for k, v in asdict(pixel).items() if k != "layout_seed"}
    return "[display.pixel]\n" + "".join(f"{k} = {_toml_value(v)}\n" for k, v in fields_.items())


@dataclass(frozen=True)
class SpectralWorld:
    """What is photographed and how.

    Attributes:
        pixel: the photographed pixel (its ``layout_seed`` is the photographed tuft layout).
        hdri: a panorama (.exr) of the project's, e.g. ``/work/shared/hdri/interior.exr``.
        lux: ambient horizontal illuminance [lx] the map is scaled to (no sun).
        viewpoints: (h cm, d m, theta deg) per series; the first is the reference.
        lengths_mm: green lengths photographed at every viewpoint.
        width: photo width = height [pixels] (even); spp: Mitsuba samples per pixel.
        checker_spp: samples per pixel of the checker photo.
        hdri_factor: the panorama is box-downsampled by this factor (both worlds use the
            downsampled map: it is the capture's ``env.exr``).
        max_depth, rr_depth: Mitsuba path depth and Russian roulette start.
        seed: seeds Mitsuba's samplers and the cameras' noise.
    """

    pixel: PixelSpec
    hdri: Path
    lux: float
    viewpoints: tuple[tuple[float, float, float], ...]
    lengths_mm: tuple[float, ...]
    width: int = 128
    spp: int = 16
    checker_spp: int = 16
    hdri_factor: int = 4
    max_depth: int = MAX_DEPTH
    rr_depth: int = RR_DEPTH
    seed: int = 0
    cameras: tuple[SpectralCamera, ...] = field(default_factory=lambda: (SpectralCamera(),))

    def __post_init__(self) -> None:
        if self.width < 8 or self.width % 2:
            raise SpectralWorldError(f"width must be even and >= 8 pixels; got {self.width}")
        if not self.viewpoints or len(self.lengths_mm) < 3:
            raise SpectralWorldError("a capture needs a viewpoint and at least 3 lengths")
        if list(self.lengths_mm) != sorted(set(self.lengths_mm)):
            raise SpectralWorldError(f"lengths must increase strictly; got {self.lengths_mm}")
        if self.pixel.specular > 0:
            raise SpectralWorldError("the spectral world renders Lambertian pixels only; set "
                                     "specular = 0")
        if not Path(self.hdri).exists():
            raise SpectralWorldError(f"no HDRI at {self.hdri}; use one of /work/shared/hdri")


def _series_toml(vp, corners, names_lengths, reference: bool) -> str:
    photos = ", ".join(f'{{ file = "{n}", length_mm = {x!r} }}' for n, x in names_lengths)
    return ("\n[[series]]\n"
            f"viewpoint = {_toml_value([float(v) for v in vp])}\n"
            f"corners = {_toml_value(np.round(corners, 4).tolist())}\n"
            f"reference = {_toml_value(reference)}\n"
            f"photos = [{photos}]\n")


def photograph_world(root: str | Path, world: SpectralWorld,
                     progress: Callable[[str], None] | None = None) -> dict[str, Path]:
    """Render ``world`` once and photograph it with each of its cameras into
    ``root/<camera name>/`` (module docstring); returns camera name -> capture directory."""
    root = Path(root)
    root.mkdir(parents=True, exist_ok=True)
    env_path = root / "env.exr"
    write_exr(env_path, downsample(load_hdri(world.hdri), world.hdri_factor)
              if world.hdri_factor > 1 else load_hdri(world.hdri))
    lighting = LightInput(env_path, world.lux).lighting()
    display = DisplaySpec(world.pixel)
    cams = world.cameras
    dirs = {c.name: root / c.name for c in cams}
    for d in dirs.values():
        d.mkdir(exist_ok=True)
        shutil.copyfile(env_path, d / "env.exr")
        write_chart_csv(d / "chart.csv")
        (d / "true_pixel.toml").write_text(pixel_toml(world.pixel))
        write_sensitivities(d / SENSITIVITIES_CSV, CameraSensitivities.from_colour(d.name))
    scenes = root / "scenes"
    renders: dict[tuple[int, float], tuple[list, NDArray, NDArray, dict]] = {}
    for i, vp in enumerate(world.viewpoints):
        for x in world.lengths_mm:
            if progress:
                progress(f"rendering ({vp[0]:g}, {vp[1]:g}, {vp[2]:g}) at {x:g} mm")
            sd = scenes / f"v{i:02d}_{x:05.2f}mm"
            doc = export_scene(sd, display, lighting, Viewpoint(*vp), float(x))
            imgs, xyz = render_pixel(sd, cams, world.spp, world.width,
                                     seed=world.seed + len(renders), max_depth=world.max_depth,
                                     rr_depth=world.rr_depth)
            (x0, y0), w = quad_coverage(doc, world.width)
            quad_xyz = np.einsum("hwc,hw->c", xyz[y0:y0 + w.shape[0], x0:x0 + w.shape[1]],
                                 w) / w.sum()
            renders[i, float(x)] = (imgs, quad_pixels(doc, world.width), quad_xyz, doc)
    first = next(iter(sorted(scenes.iterdir())))
    whites, white_xyz = render_white_card(first, cams, seed=world.seed)
    checker, checker_xyz, chart_corners = render_checker(first, cams, spp=world.checker_spp,
                                                         seed=world.seed + 1)
    truth = {"white_card_xyz": white_xyz.tolist(), "world": {
        "hdri": str(world.hdri), "lux": world.lux, "width": world.width, "spp": world.spp,
        "max_depth": world.max_depth, "rr_depth": world.rr_depth,
        "layout_seed": world.pixel.layout_seed},
        "quads": [{"viewpoint": list(world.viewpoints[i]), "length_mm": x,
                   "xyz": r[2].tolist()} for (i, x), r in renders.items()]}
    for k, cam in enumerate(cams):
        d = dirs[cam.name]
        e = cam.exposure_for(whites[k])
        cam.photograph(d / "checker.dng", checker[k], whites[k], e, seed=world.seed)
        text = (f"checker_chart = {_toml_value(str((d / 'chart.csv').resolve()))}\n"
                f'hdri = "env.exr"\nambient_lux = {float(world.lux)!r}\n'
                f'checker_raw = "checker.dng"\nchecker_corners = '
                f"{_toml_value(np.round(chart_corners, 4).tolist())}\n"
                f'camera_sensitivities = "{SENSITIVITIES_CSV}"\n')
        shot = 1
        for i, vp in enumerate(world.viewpoints):
            names = []
            for x in world.lengths_mm:
                imgs, corners, _, _ = renders[i, float(x)]
                name = f"v{i:02d}_{x:05.2f}mm.dng"
                cam.photograph(d / name, imgs[k], whites[k], e, seed=world.seed + shot)
                shot += 1
                names.append((name, float(x)))
            text += _series_toml(vp, renders[i, float(world.lengths_mm[0])][1], names, i == 0)
        (d / "capture.toml").write_text(text)
        (d / "truth.json").write_text(json.dumps(
            {**truth, "camera": cam.name, "white_card_rgb": whites[k].tolist(),
             "checker_rgb_image_mean": checker[k].mean((0, 1)).tolist(),
             "exposure_e_per_unit": e}, indent=1))
    return dirs
