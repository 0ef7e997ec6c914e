"""Photograph a simulated "real" world with the virtual camera into a capture directory.

No real capture ships with the project, so tests and demos make one: the renderer's path-traced
view of a grass pixel (:meth:`grassd.sim.renderer.Renderer.preview`, linear Rec.709 radiance)
at each green length and viewpoint, and an analytic colour checker lying at the display under
the same light, are exposed by a :class:`grassd.calib.virtual_camera.VirtualCamera` into DNG
files, with a ``capture.toml`` manifest that ``grassd validate`` reads.

The photographed world may differ from the model the manifest describes (``real_pixel`` vs
``model_pixel``: blade splay, albedo errors), and the camera adds its own colour response,
white balance, noise and quantisation; validation must see exactly those differences.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, fields, replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from grassd.calib.charts import get_chart
from grassd.calib.checker_photo import checker_scene
from grassd.calib.virtual_camera import VirtualCamera
from grassd.daemon.core.store.atomic import atomic_write_text
from grassd.daemon.offline.validate import (
    MANIFEST_NAME,
    CaptureManifest,
    Photo,
    Series,
    default_renderer,
    manifest_to_toml,
)
from grassd.sim.light_input import LightInput
from grassd.sim.scene import PixelSpec, RenderSettings

if TYPE_CHECKING:
    from grassd.sim.lighting import Lighting
    from grassd.sim.renderer import Renderer


def capture_world(out_dir: str | Path, light: LightInput,
                  viewpoints: Sequence[tuple[float, float, float]], lengths_mm: Sequence[float],
                  *, real_pixel: PixelSpec | None = None,
                  model_pixel: Mapping[str, float | Sequence[float]] | None = None,
                  camera: VirtualCamera | None = None, renderer: Renderer | None = None,
                  lighting: Lighting | None = None, width: int = 160, spp: int = 32,
                  max_bounces: int = RenderSettings.max_bounces, seed: int = 0,
                  chart: str = "spydercheckr-24",
                  progress: Callable[[str], None] | None = None,
                  cache: dict | None = None, extra_trials: int = 0) -> CaptureManifest:
    """Photograph ``real_pixel`` (a :class:`grassd.sim.scene.PixelSpec`; default the model's)
    under ``light`` from every viewpoint (h cm, d m, theta deg) at every length (mm) into DNGs
    in ``out_dir`` and write ``capture.toml``; returns the manifest.

    ``model_pixel``: the PixelSpec fields the manifest gives the simulation (default: none,
    i.e. the default PixelSpec). ``width``/``spp``: preview resolution and samples per pixel;
    ``max_bounces``: the renderer's default lets Russian roulette alone end a path (unbiased).
    The first viewpoint is marked the reference. Exposure is fixed for the session from the
    white-card radiance, as a photographer would set it. ``cache``: a dict that keeps the
    rendered views (keyed by everything they depend on but the lighting, so use one cache per
    lighting), to photograph one world with several cameras without rendering it again.
    ``extra_trials``: further series at the first viewpoint, as a repeatability test (paper
    section 4.1.1): in trial ``t`` the blades rest differently (``layout_seed + t``) and the
    render and camera noise are new, as when a real pixel's grass is moved out and back in.
    """
    from grassd.daemon.core.calibration.simulation import white_radiance
    from grassd.sim.scene import DisplaySpec, Viewpoint

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    camera = camera or VirtualCamera()
    lighting = lighting if lighting is not None else light.lighting()
    given = {k: tuple(v) if isinstance(v, Sequence) else v
             for k, v in (model_pixel or {}).items()}
    real_pixel = real_pixel if real_pixel is not None else PixelSpec(**given)
    if renderer is None:
        renderer = default_renderer()
    white = white_radiance(lighting)
    k = camera.exposure_for(white)
    ref_chart = get_chart(chart)
    img, chart_corners = checker_scene(ref_chart, white, 384, 256)
    checker = camera.photograph(out / "checker.dng", img, white, electrons_per_unit=k,
                                seed=seed)
    if extra_trials < 0 or (extra_trials and not viewpoints):
        raise ValueError("extra_trials must be >= 0 and needs a first viewpoint")
    plan = [(vp, real_pixel, seed) for vp in viewpoints] + [
        (viewpoints[0], replace(real_pixel, layout_seed=real_pixel.layout_seed + t),
         seed + 7919 * t) for t in range(1, extra_trials + 1)]
    series = []
    shot = 1
    for i, (vp, pixel, render_seed) in enumerate(plan):
        photos = []
        display = DisplaySpec(pixel)
        settings = RenderSettings(samples=16, replicates=2, max_bounces=max_bounces,
                                  seed=render_seed)
        for x in lengths_mm:
            if progress:
                progress(f"photographing ({vp[0]:g}, {vp[1]:g}, {vp[2]:g}) at {x:g} mm")
            key = (pixel, tuple(vp), float(x), width, spp, max_bounces, render_seed)
            if cache is not None and key in cache:
                view, quad = cache[key]
            else:
                view, quad = renderer.preview(display, lighting, Viewpoint(*vp), float(x),
                                              width=width, spp=spp, settings=settings)
                if cache is not None:
                    cache[key] = (view, quad)
            path = camera.photograph(out / f"v{i:02d}_{x:05.2f}mm.dng", view, white,
                                     electrons_per_unit=k, seed=seed + shot)
            shot += 1
            photos.append(Photo(path, float(x), tuple(map(tuple, np.asarray(quad).tolist()))))
        series.append(Series(tuple(float(v) for v in vp), tuple(photos), reference=i == 0))
    manifest = CaptureManifest(root=out, light=light, checker_photo=checker,
                               checker_corners=tuple(map(tuple, chart_corners.tolist())),
                               series=tuple(series), chart=chart, pixel=given)
    atomic_write_text(out / MANIFEST_NAME, manifest_to_toml(manifest))
    return manifest


def pixel_fields(pixel: PixelSpec) -> dict[str, float | list[float]]:
    """PixelSpec fields that differ from the defaults (for a manifest's ``[pixel]`` table)."""
    default = PixelSpec()
    d = asdict(pixel)
    return {f.name: (list(d[f.name]) if isinstance(d[f.name], tuple) else d[f.name])
            for f in fields(PixelSpec) if d[f.name] != getattr(default, f.name)}
