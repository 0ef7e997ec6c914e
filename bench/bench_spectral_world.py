"""``grassd validate`` and ``grassd fit`` in a world grassd did not render (:mod:`grassd.rigs.
spectral_world`): the exported pixel rendered by Mitsuba's spectral path tracer, photographed by
cameras defined by their spectral sensitivities (Nikon D5100, Sigma SD Merrill), into DNGs.

For each world (materials, light and tuft layout of its own) and camera, read through the
camera's own sensitivities (the capture names them) and through the checker's correction, it
prints:

* the checker correction's error (leave-one-out mean / max dE00, and the form chosen);
* with the true materials typed in (``[pixel]`` = the photographed pixel, its layout left to
  the model): the Frechet distance at every viewpoint (goal <= 0.6) and the mean CIEDE2000
  between the photos' and the simulation's colours;
* fitted from the defaults on two viewpoints, the third held out: each albedo's CIEDE2000
  from the truth (goals: yellow and green <= 2, base <= 4), the held-out Frechet against the
  true materials' (goal <= max(0.5, true + 0.25)), the notes of what was held at its prior.

Prints numbers, asserts nothing. Needs the test extra (Mitsuba) and ../shared/hdri. Run:
``python -m bench.bench_spectral_world`` (2 CPU cores, Mitsuba's llvm variant: about 10
minutes; ``SPECTRAL_QUICK=1``: one world, one camera, smaller photos).
"""

from __future__ import annotations

import os
import tempfile
import time
from dataclasses import replace
from pathlib import Path

from colour import delta_E

from bench import HDRI_DIR
from grassd.daemon.offline.fit import FitError, fit_capture
from grassd.daemon.offline.validate import default_renderer, load_manifest, validate_capture
from grassd.rigs.fit_worlds import ALBEDOS, albedo_de00, model_fields
from grassd.rigs.spectral_camera import SpectralCamera
from grassd.rigs.spectral_world import SpectralWorld, photograph_world
from grassd.sim.scene import PixelSpec, RenderSettings

QUICK = os.environ.get("SPECTRAL_QUICK") == "1"
VIEWS = ((170.0, 2.0, 0.0), (200.0, 0.8, 90.0), (140.0, 1.5, 45.0))  #: the last is held out
LENGTHS = (0.0, 4.0, 8.0, 12.0, 16.0, 20.0)
CAMERAS = ("nikon-d5100",) if QUICK else ("nikon-d5100", "sigma-sdmerrill")

#: name: (photographed pixel, HDRI of ../shared/hdri, ambient lux). Chosen here, not the
#: review's: a pale rose grass under indoor light (the interreflections the 3-bounce cut
#: darkened), a dark moss-green turf in a forest's diffuse light, and a dry straw-coloured
#: grass on reddish soil in a city street's light.
WORLDS: dict[str, tuple[PixelSpec, str, float]] = {
    "rose": (PixelSpec(yellow_srgb=(230.0, 210.0, 200.0), green_srgb=(225.0, 150.0, 175.0),
                       base_srgb=(205.0, 180.0, 185.0), layout_seed=211), "interior", 600.0),
    "moss": (PixelSpec(yellow_srgb=(150.0, 150.0, 70.0), green_srgb=(70.0, 100.0, 45.0),
                       base_srgb=(120.0, 110.0, 70.0), layout_seed=307), "forest", 6000.0),
    "straw": (PixelSpec(yellow_srgb=(215.0, 185.0, 110.0), green_srgb=(180.0, 160.0, 95.0),
                        base_srgb=(140.0, 90.0, 70.0), layout_seed=419), "city", 12000.0),
}


def main() -> None:
    """Photograph each world, then validate and fit each camera's capture."""
    from grassd.sim.backend import init

    init("cpu")
    renderer = default_renderer()
    settings = RenderSettings(samples=4096, replicates=4)
    for name, (pixel, hdri, lux) in list(WORLDS.items())[:1 if QUICK else None]:
        world = SpectralWorld(pixel=pixel, hdri=Path(HDRI_DIR) / f"{hdri}.exr", lux=lux,
                              viewpoints=VIEWS, lengths_mm=LENGTHS,
                              width=64 if QUICK else 96, spp=8 if QUICK else 16,
                              cameras=tuple(SpectralCamera(c) for c in CAMERAS))
        with tempfile.TemporaryDirectory() as tmp:
            t = time.perf_counter()
            dirs = photograph_world(tmp, world)
            print(f"{name} ({hdri} {lux:g} lx): photographed in {time.perf_counter() - t:.0f} s",
                  flush=True)
            for cam, d in dirs.items():
                captured = load_manifest(d / "capture.toml")
                lighting = captured.light.lighting()
                for manifest in (captured, replace(captured, sensitivities=None)):
                    _validate_and_fit(manifest, cam, pixel, renderer, settings, lighting)


def _validate_and_fit(manifest, cam: str, pixel: PixelSpec, renderer, settings,
                      lighting) -> None:
    """Print the true materials' validation and the two-view fit of one capture, read through
    the camera (the capture names its sensitivities) or the checker's correction."""
    how = "camera" if manifest.sensitivities else "correction"
    true = replace(manifest, pixel=model_fields(pixel))
    v = validate_capture(true, renderer=renderer, settings=settings, lighting=lighting,
                         layouts=4)
    frechet = ", ".join(f"{c.label} {c.frechet:.2f}" for c in v.viewpoints)
    colour = ", ".join(f"{float(delta_E(c.real_lab, c.sim_lab, method='CIE 2000').mean()):.2f}"
                       for c in v.viewpoints)
    print(f"  {cam}, read through the {how} ({v.chain}): checker {v.ccm.form} leave-one-out "
          f"{v.ccm.loo_mean_de00:.2f} / {v.ccm.loo_max_de00:.2f} dE00; true materials: "
          f"Frechet {frechet}; mean colour dE00 {colour}", flush=True)
    true_held = v.viewpoints[-1].frechet
    t = time.perf_counter()
    try:
        fit = fit_capture(manifest, holdout=[VIEWS[-1]], renderer=renderer, lighting=lighting)
    except FitError as exc:
        print(f"    fit refused: {exc}", flush=True)
        return
    held = next(vp for vp in fit.viewpoints if vp.held_out)
    de = ", ".join(f"{a.split('_')[0]} {albedo_de00(fit.pixel[a], getattr(pixel, a)):.2f}"
                   for a in ALBEDOS if a in fit.pixel)
    print(f"    fit (2 views) {time.perf_counter() - t:.0f} s: {de} dE00; held out "
          f"{held.fitted.frechet:.2f} (true materials {true_held:.2f}, defaults "
          f"{held.start.frechet:.2f}); chi2 {fit.chi2:.1f} on {fit.dof}", flush=True)
    for note in fit.notes:
        print(f"    note: {note}")


if __name__ == "__main__":
    main()
