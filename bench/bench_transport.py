"""Light transport benchmark: what RGB transport costs the daemon's characteristic.

The daemon simulates its grass in linear Rec.709 (RGB light transport) and reads the result
through the CIE observer. Spectral transport gives each path the product of the materials'
reflectance *spectra* times the light's spectrum instead. Both can be evaluated on the same
recorded paths: the renderer's albedo polynomial (:mod:`grassd.sim.albedo_terms`, deep, degree 8
with the tail term) is evaluated once at the albedos' Rec.709 values (what the RGB trace gives,
to the tail) and once per wavelength on the materials' Jakob-Hanika spectra in the light's
upsampled spectra (:func:`grassd.calib.spectral_prediction.transfer`, read by the CIE observer).
The white card reads the same in both (the light's basis is fitted so), so what differs is the
transport alone, without Monte Carlo noise between the two.

For each pixel and light, at two viewpoints and 21 lengths, it prints the absolute colour's
CIEDE2000 between the two (worst length), the characteristic's (OGCD) largest difference, and
the trace's and the recording's warm times, and the daemon's characteristic
(:func:`grassd.daemon.core.calibration.simulation.simulate_curve`) with either transport: its
warm time at 21 lengths.

With ``TRANSPORT_MITSUBA=1`` (needs the test extra and ../shared/hdri) it measures instead how
close each transport comes to Mitsuba's spectral path tracer read by the CIE observer
(:mod:`grassd.rigs.spectral_world`: its own transport, Jakob-Hanika materials, the map
upsampled), for the photographed tuft layout itself, each normalised by its own white card:
the absolute colour's CIEDE2000 and the OGCD's difference at every length.

Run: ``python -m bench.bench_transport`` (2 CPU cores: about 4 minutes; the Mitsuba part about
10).
"""

from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np
from colour import delta_E

from bench import HDRI_DIR
from grassd.calib.camera_response import cie_observer
from grassd.calib.colour_spaces import M_XYZ_TO_REC709, prophoto_to_lab, rec709_to_prophoto
from grassd.calib.spectral_prediction import sigmoid_spectra, transfer
from grassd.sim.albedo_terms import monomial_values
from grassd.sim.scene import DisplaySpec, PixelSpec, RenderSettings, Viewpoint

LENGTHS = np.arange(0.0, 20.01, 1.0)
VIEWS = (Viewpoint(170, 2, 0), Viewpoint(140, 1.5, 45))

#: name: (pixel, HDRI of ../shared/hdri, ambient lux)
CASES: dict[str, tuple[PixelSpec, str, float]] = {
    "default green, courtyard": (PixelSpec(), "courtyard", 8000.0),
    "pink, interior": (PixelSpec(yellow_srgb=(225.0, 200.0, 205.0),
                                 green_srgb=(235.0, 140.0, 185.0),
                                 base_srgb=(215.0, 185.0, 195.0)), "interior", 500.0),
    "olive, forest": (PixelSpec(yellow_srgb=(190.0, 180.0, 90.0),
                                green_srgb=(110.0, 125.0, 45.0),
                                base_srgb=(120.0, 100.0, 60.0)), "forest", 3000.0),
    "rose, city": (PixelSpec(yellow_srgb=(230.0, 170.0, 120.0),
                             green_srgb=(200.0, 60.0, 90.0),
                             base_srgb=(150.0, 110.0, 100.0)), "city", 10000.0),
    "cyan, studio": (PixelSpec(yellow_srgb=(200.0, 220.0, 120.0),
                               green_srgb=(40.0, 170.0, 190.0),
                               base_srgb=(90.0, 120.0, 130.0)), "studio", 1500.0),
}


def lab(rgb: np.ndarray, white: np.ndarray) -> np.ndarray:
    """D50 CIELAB of linear Rec.709 radiance normalised by the white card's (the daemon's
    chain without a correction)."""
    return prophoto_to_lab(rec709_to_prophoto(np.clip(rgb / white, 0.0, None)))


#: (h cm, d m, theta deg) and lengths (mm) of the Mitsuba comparison
MITSUBA_VIEWS = ((170.0, 2.0, 0.0), (140.0, 1.5, 45.0))
MITSUBA_LENGTHS = (0.0, 5.0, 10.0, 15.0, 20.0)
MITSUBA_CASES = ("pink, interior", "cyan, studio", "default green, courtyard")


def mitsuba_comparison(width: int = 64, spp: int = 256) -> None:
    """grassd's characteristic with each transport against Mitsuba's spectral render."""
    import tempfile
    from dataclasses import replace

    from grassd.daemon.core.calibration.simulation import simulate_curve, white_radiance
    from grassd.daemon.core.calibration.transport import SpectralTransport
    from grassd.rigs.mitsuba_scene import configure_llvm
    from grassd.rigs.spectral_world import observed_quads
    from grassd.sim import backend
    from grassd.sim.hdri import downsample, load_hdri, write_exr
    from grassd.sim.light_input import LightInput
    from grassd.sim.renderer import Renderer

    print(f"Mitsuba: llvm {'yes' if configure_llvm() else 'no (scalar variant, slow)'}")
    backend.init("cpu")
    renderer = Renderer.shared()
    x = np.asarray(MITSUBA_LENGTHS)
    print("  case                       view            transport  dE00 abs at each length"
          "            dOGCD at each length")
    for name in MITSUBA_CASES:
        pixel, hdri, lux = CASES[name]
        pixel = replace(pixel, layout_seed=977)
        display = DisplaySpec(pixel)
        with tempfile.TemporaryDirectory() as tmp:
            env = Path(tmp) / "env.exr"
            write_exr(env, downsample(load_hdri(HDRI_DIR / f"{hdri}.exr"), 4))
            lighting = LightInput(env, lux).lighting()
            t0 = time.perf_counter()
            truth = {vp: observed_quads(tmp, display, lighting, Viewpoint(*vp), x, spp, width)
                     for vp in MITSUBA_VIEWS}
            t_mi = time.perf_counter() - t0
        white = white_radiance(lighting)
        spectral = SpectralTransport.of(display, lighting, 16)
        settings = RenderSettings(samples=16384, replicates=16, seed=3)
        for vp in MITSUBA_VIEWS:
            quads, white_xyz = truth[vp]
            ref = lab(quads @ M_XYZ_TO_REC709.T, M_XYZ_TO_REC709 @ white_xyz)
            ref_ogcd = delta_E(ref[:1], ref)
            for label, how in (("rgb", None), ("spectral", spectral)):
                curve = simulate_curve(renderer, display, lighting, Viewpoint(*vp), x,
                                       settings, spectral=how)
                ours = lab(curve.rgb_linear, white)
                de = delta_E(ours, ref)
                d_ogcd = curve.ogcd - ref_ogcd
                print(f"  {name:26s} {Viewpoint(*vp).label():15s} {label:9s}  "
                      f"{' '.join(f'{v:4.2f}' for v in de)}    "
                      f"{' '.join(f'{v:+5.2f}' for v in d_ogcd)}")
        print(f"  ({name}: Mitsuba {len(x) * len(truth)} renders of {width}^2 x {spp} spp, "
              f"{t_mi:.0f} s; grassd 16384 x 16 paths)")


def main() -> None:
    from grassd.daemon.core.calibration.simulation import white_radiance
    from grassd.daemon.core.calibration.transport import light_spectra_basis
    from grassd.sim import backend
    from grassd.sim.lighting import build_lighting
    from grassd.sim.renderer import Renderer

    backend.init(os.environ.get("GRASSD_BENCH_ARCH", "cpu"))
    renderer = Renderer.shared()
    samples, reps = int(os.environ.get("TRANSPORT_SAMPLES", 4096)), int(os.environ.get(
        "TRANSPORT_REPLICATES", 4))
    observer = cie_observer() @ M_XYZ_TO_REC709.T  # (n, 3): the observer read as Rec.709
    print(f"RGB vs spectral transport, the same recorded paths ({samples} x {reps} per length)")
    print("  case                       view            dE00 abs (worst)   dOGCD (worst)  "
          "OGCD@20")
    for name, (pixel, hdri, lux) in CASES.items():
        lighting = build_lighting(HDRI_DIR / f"{hdri}.exr", lux)
        display = DisplaySpec(pixel)
        white = white_radiance(lighting)
        basis = light_spectra_basis(lighting)
        albedo = pixel.albedo_linear
        spectra = monomial_values(sigmoid_spectra(albedo), 0.0, 8)  # (M, n)
        to_rgb = transfer(spectra, observer, basis)  # (M, 3, 3)
        mono = monomial_values(albedo, 0.0, 8)  # (M, 3)
        settings = RenderSettings(samples=samples, replicates=reps)
        for view in VIEWS:
            terms = renderer.albedo_terms(display, lighting, view, LENGTHS, settings)
            c = terms.coefficients.mean(axis=0)  # (n, M, 3)
            rgb = np.einsum("nmc,mc->nc", c, mono)
            spectral = np.einsum("nmk,mkc->nc", c, to_rgb)
            a, b = lab(rgb, white), lab(spectral, white)
            de = delta_E(a, b)
            d_ogcd = delta_E(b[:1], b) - delta_E(a[:1], a)
            worst, worst_o = int(np.argmax(de)), int(np.argmax(np.abs(d_ogcd)))
            print(f"  {name:26s} {view.label():15s} {de[worst]:5.2f} @ {LENGTHS[worst]:4.0f} mm"
                  f"    {d_ogcd[worst_o]:+5.2f} @ {LENGTHS[worst_o]:3.0f} mm"
                  f"  {delta_E(a[:1], a)[-1]:6.2f}")
    pixel, hdri, lux = CASES["pink, interior"]
    lighting = build_lighting(HDRI_DIR / f"{hdri}.exr", lux)
    display, settings = DisplaySpec(pixel), RenderSettings(samples=4096, replicates=8)
    renderer.characteristic(display, lighting, VIEWS[0], LENGTHS, settings)
    renderer.albedo_terms(display, lighting, VIEWS[0], LENGTHS, settings)
    for what, run in (("trace", renderer.characteristic), ("recording", renderer.albedo_terms)):
        walls = []
        for _ in range(3):
            t0 = time.perf_counter()
            run(display, lighting, VIEWS[0], LENGTHS, settings)
            walls.append(time.perf_counter() - t0)
        print(f"  warm 21-length {what}, 4096 x 8 paths: median {np.median(walls):.3f} s")
    from grassd.daemon.core.calibration.simulation import simulate_curve
    from grassd.daemon.core.calibration.transport import SpectralTransport

    spectral = SpectralTransport.of(display, lighting, 16)
    for label, how in (("rgb", None), ("spectral (1/16 recorded)", spectral)):
        walls = []
        for seed in range(4):
            t0 = time.perf_counter()
            simulate_curve(renderer, display, lighting, VIEWS[0], LENGTHS,
                           RenderSettings(samples=4096, replicates=8, seed=seed), spectral=how)
            walls.append(time.perf_counter() - t0)
        print(f"  warm 21-length characteristic, {label}: median {np.median(walls[1:]):.3f} s")


if __name__ == "__main__":
    if os.environ.get("TRANSPORT_MITSUBA"):
        mitsuba_comparison()
    else:
        main()
