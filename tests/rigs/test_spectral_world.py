"""The spectral world (grassd.rigs.spectral_world): a pixel grassd did not render, photographed
by a camera with a real sensor's spectral sensitivities, read by grassd's own chain.

Plain tier: the camera on a flat spectrum, the DNG round trip, the checker's colours, and a
tiny world that ``grassd validate`` reads. Long tier (``GRASSD_TEST_LONG=1``): today's
failures the rig reproduces, asserted as measured (docs/rigs/spectral_world.md), so a fix
that moves them has to move these bands."""

from __future__ import annotations

import json
import subprocess
import sys
import time
import tomllib
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("mitsuba", reason="mitsuba is a test extra: pip install -e '.[test]'")

from grassd.rigs.spectral_camera import (  # noqa: E402
    CAMERAS,
    COLORIMETRIC,
    WAVELENGTHS,
    SpectralCamera,
    SpectralCameraError,
    checker_reflectances,
    cie_observer,
    d65,
    integrate,
)
from grassd.rigs.spectral_world import (  # noqa: E402
    SpectralWorld,
    SpectralWorldError,
    film_channels,
    photograph_world,
    render_checker,
    render_white_card,
    set_spectral_variant,
)
from grassd.sim.export import export_scene  # noqa: E402
from grassd.sim.lighting import build_lighting  # noqa: E402
from grassd.sim.scene import DisplaySpec, PixelSpec, Viewpoint  # noqa: E402

GRASSD = Path(sys.executable).with_name("grassd")


def _grassd(*args: str, timeout: float = 1800) -> subprocess.CompletedProcess:
    """Run the grassd command line (never imported: the daemon's modules are its own)."""
    return subprocess.run([str(GRASSD), *args], capture_output=True, text=True,
                          timeout=timeout)


# ---------------------------------------------------------------------------- plain tier
@pytest.mark.parametrize("name", list(CAMERAS))
def test_specfilm_integrates_the_sensitivities_over_a_flat_spectrum(name):
    """Under a sky of radiance 1 at every wavelength, Mitsuba's specfilm with the camera's
    channels stores ``integral S_c d lambda``, as the camera's own response computes it."""
    import mitsuba as mi

    set_spectral_variant()
    cam = SpectralCamera(name)
    scene = mi.load_dict({
        "type": "scene", "integrator": {"type": "path", "max_depth": 2},
        "sensor": {"type": "perspective", "fov": 20,
                   "film": {"type": "specfilm", "width": 16, "height": 16,
                            "rfilter": {"type": "box"}, **film_channels([cam])},
                   "sampler": {"type": "independent", "sample_count": 64}},
        "sky": {"type": "constant", "radiance": {"type": "uniform", "value": 1.0}}})
    img = np.array(mi.render(scene, seed=1), np.float64)
    got = img.reshape(-1, img.shape[-1]).mean(0)
    want = cam.response(np.ones(len(WAVELENGTHS)))
    np.testing.assert_allclose(got[:3], want, rtol=0.015)
    np.testing.assert_allclose(got[3:], integrate(np.ones(len(WAVELENGTHS)), cie_observer()),
                               rtol=0.015)  # the truth's channels: the CIE observer's areas


def test_profiles_map_white_to_one_and_only_the_observer_is_colorimetric():
    """The DNG profile maps the D65 white to a largest channel of 1; neither real camera meets
    the Luther condition: a 3x3 of XYZ misses its response to the checker (0.5-0.8 % of
    white); the CIE observer's camera does (its profile is exact)."""
    xyz = integrate(d65(), cie_observer())
    for name in CAMERAS:
        cam = SpectralCamera(name)
        assert np.isclose((cam.xyz_to_camera @ (xyz / xyz[1])).max(), 1.0)
        if name == COLORIMETRIC:
            assert cam.luther_residual() < 1e-9, cam.luther_residual()
        else:
            assert 2e-3 < cam.luther_residual() < 0.02, (name, cam.luther_residual())
    with pytest.raises(SpectralCameraError, match="unknown camera"):
        SpectralCamera("canon-5d")


def test_dng_round_trip_keeps_levels_profile_and_white(tmp_path):
    """A flat raw RGB image photographed and read back by LibRaw: each Bayer channel's mean is
    the exposed level, the profile and the white balance are the camera's."""
    rawpy = pytest.importorskip("rawpy")
    cam = SpectralCamera("nikon-d5100", blur_px=0.0)
    white = np.array([0.8, 1.0, 0.6])
    k = cam.exposure_for(white)
    rgb = np.array([0.4, 0.7, 0.2])
    path = cam.photograph(tmp_path / "flat.dng", np.broadcast_to(rgb, (64, 64, 3)), white, k, 3)
    vc = cam.virtual_camera()
    gain = (vc.white_level - vc.black_level_dn) / cam.full_well_e
    with rawpy.imread(str(path)) as raw:
        data = raw.raw_image_visible.astype(np.float64)
        colours = raw.raw_colors_visible
        got = [data[np.isin(colours, c)].mean() for c in ([0], [1, 3], [2])]
        np.testing.assert_allclose(got, vc.black_level_dn + rgb * k * gain, rtol=0.003)
        wb = np.asarray(raw.camera_whitebalance[:3])
        np.testing.assert_allclose(wb / wb[1], white[1] / white, rtol=1e-3)
    import tifffile

    with tifffile.TiffFile(path) as tif:
        ratios = np.array(tif.pages[0].tags[50721].value, np.float64).reshape(9, 2)
    np.testing.assert_allclose((ratios[:, 0] / ratios[:, 1]).reshape(3, 3), cam.xyz_to_camera,
                               atol=2e-4)  # ColorMatrix1
    assert k * white.max() == pytest.approx(cam.white_fraction * cam.full_well_e)
    with pytest.raises(SpectralCameraError, match="non-negative"):
        cam.photograph(tmp_path / "bad.dng", -np.ones((4, 4, 3)), white, k, 0)


def _uniform_sky_dir(tmp_path) -> Path:
    """An exported scene under a sky of RGB (1, 1, 1) everywhere: Mitsuba emits CIE D65."""
    sky = build_lighting(np.ones((16, 32, 3), np.float32), 1000.0)
    export_scene(tmp_path / "sky", DisplaySpec(), sky, Viewpoint(170, 2, 0), 10.0)
    return tmp_path / "sky"


def test_checker_patches_are_their_spectra_under_the_sky(tmp_path):
    """Each patch of the checker photo, over the white card's, is the camera's response to the
    patch's reflectance spectrum under D65 over its response to D65 (within 2.5 %)."""
    scene_dir = _uniform_sky_dir(tmp_path)
    cam = SpectralCamera("nikon-d5100")
    white, _ = render_white_card(scene_dir, [cam], spp=64)
    imgs, xyz, corners = render_checker(scene_dir, [cam], width=192, spp=16)
    _, refl = checker_reflectances()
    want = cam.response(refl * d65()) / cam.response(d65())
    tl, tr, br, bl = corners
    got = []
    for k in range(24):
        row, col = divmod(k, 6)
        u, v = (col + 0.5) / 6, (row + 0.5) / 4
        cx, cy = (1 - v) * ((1 - u) * tl + u * tr) + v * ((1 - u) * bl + u * br)
        win = imgs[0][int(cy) - 7:int(cy) + 8, int(cx) - 7:int(cx) + 8]
        got.append(win.reshape(-1, 3).mean(0) / white[0])
    # spectral sampling noise: 0.5 % standard deviation over the patches at 16 spp
    np.testing.assert_allclose(np.array(got), want, rtol=0.025, atol=1e-3)
    assert xyz.shape == imgs[0].shape == (192, 192, 3)


def test_a_tiny_world_is_a_capture_grassd_validate_reads(tmp_path):
    """One viewpoint, three lengths, two cameras, 32-pixel photos: the capture directory has
    what capture.toml names, and ``grassd validate`` develops it and compares it."""
    world = SpectralWorld(
        pixel=PixelSpec(green_srgb=(235.0, 140.0, 185.0), layout_seed=7),
        hdri=Path(__file__).resolve().parents[3] / "shared" / "hdri" / "studio.exr", lux=800.0,
        viewpoints=((170.0, 2.0, 0.0),), lengths_mm=(0.0, 10.0, 20.0), width=64, spp=4,
        checker_spp=4, hdri_factor=8,
        cameras=(SpectralCamera("nikon-d5100"), SpectralCamera("sigma-sdmerrill")))
    if not world.hdri.exists():
        pytest.skip(f"{world.hdri} not present (CI provides ../shared beside the clone)")
    t = time.perf_counter()
    dirs = photograph_world(tmp_path, world)
    print(f"tiny world: {time.perf_counter() - t:.1f} s")
    assert set(dirs) == {"nikon-d5100", "sigma-sdmerrill"}
    for d in dirs.values():
        doc = tomllib.loads((d / "capture.toml").read_text())
        assert (d / doc["hdri"]).exists() and (d / doc["checker_raw"]).exists()
        assert Path(doc["checker_chart"]).exists()
        (series,) = doc["series"]
        assert [p["length_mm"] for p in series["photos"]] == [0.0, 10.0, 20.0]
        assert all((d / p["file"]).exists() for p in series["photos"])
        assert "green_srgb = [235.0, 140.0, 185.0]" in (d / "true_pixel.toml").read_text()
        truth = json.loads((d / "truth.json").read_text())
        assert len(truth["quads"]) == 3 and truth["white_card_xyz"][1] > 0
    t = time.perf_counter()
    r = _grassd("validate", str(dirs["nikon-d5100"]), "--samples", "64", "--replicates", "2",
                "-q", "--json", str(tmp_path / "v.json"), timeout=600)
    print(f"grassd validate: {time.perf_counter() - t:.1f} s")
    assert r.returncode == 0, r.stdout + r.stderr
    assert "deprecated" not in r.stderr
    report = json.loads((tmp_path / "v.json").read_text())
    assert report["viewpoints"][0]["lengths_mm"] == [0.0, 10.0, 20.0]
    assert report["ccm"]["mean_de00"] < 3.0, report["ccm"]
    assert report["camera"]["model"] == "Nikon 5100 (NPL)", report["camera"]
    # the capture names the camera's sensitivities: the photos are read through them
    assert report["colour_chain"] == "camera"
    assert "camera's spectral sensitivities" in r.stdout


def test_refuses_what_it_cannot_render(tmp_path):
    hdri = tmp_path / "none.exr"
    with pytest.raises(SpectralWorldError, match="no HDRI"):
        SpectralWorld(PixelSpec(), hdri, 500.0, ((170.0, 2.0, 0.0),), (0.0, 10.0, 20.0))
    with pytest.raises(SpectralWorldError, match="Lambertian"):
        SpectralWorld(PixelSpec(specular=0.05), hdri, 500.0, ((170.0, 2.0, 0.0),),
                      (0.0, 10.0, 20.0))
    with pytest.raises(SpectralWorldError, match="increase strictly"):
        SpectralWorld(PixelSpec(), hdri, 500.0, ((170.0, 2.0, 0.0),), (0.0, 20.0, 10.0))


# ----------------------------------------------------------------------------- long tier
#: A turf of its own for the long tier (not the bench's worlds): sage-green blades with
#: straw-yellow ones over a brown soil, in a courtyard's daylight.
SAGE = PixelSpec(yellow_srgb=(200.0, 185.0, 115.0), green_srgb=(115.0, 140.0, 85.0),
                 base_srgb=(115.0, 95.0, 75.0), layout_seed=331)
SAGE_VIEWS = ((170.0, 2.0, 0.0), (200.0, 0.8, 90.0), (140.0, 1.5, 45.0))  # the last held out


@pytest.fixture(scope="module")
def sage(tmp_path_factory):
    hdri = Path(__file__).resolve().parents[3] / "shared" / "hdri" / "courtyard.exr"
    if not hdri.exists():
        pytest.skip(f"{hdri} not present (CI provides ../shared beside the clone)")
    world = SpectralWorld(pixel=SAGE, hdri=hdri, lux=15000.0, viewpoints=SAGE_VIEWS,
                          lengths_mm=(0.0, 4.0, 8.0, 12.0, 16.0, 20.0), width=96, spp=16,
                          cameras=(SpectralCamera("nikon-d5100"),
                                   SpectralCamera("sigma-sdmerrill")))
    return photograph_world(tmp_path_factory.mktemp("sage"), world)


@pytest.mark.long
@pytest.mark.parametrize("camera", ["nikon-d5100", "sigma-sdmerrill"])
def test_read_through_the_camera_the_world_keeps_its_measured_bands(sage, renderer, camera):
    """A capture that names its camera's sensitivities is read through the camera itself.
    The goals (docs/fit.md) are: the true materials within 0.6 (Frechet) at every view; fitted
    from the defaults on two views, yellow and green within 2 dE00 of the truth, the base
    within 4, and the held-out view within max(0.5, true + 0.25). This world keeps the fit's
    yellow and green goals; it misses the others, asserted as measured (with margin, below):
    the true materials' Frechet by up to 0.2 through either chain, the base (hidden under the
    blades) by up to 0.75, the held-out view by up to 0.08. The camera reads the colours as
    well as the checker's correction (the Nikon) or far better (the Sigma)."""
    from dataclasses import replace

    from colour import delta_E

    from grassd.daemon.offline.fit import fit_capture
    from grassd.daemon.offline.validate import load_manifest, validate_capture
    from grassd.rigs.fit_worlds import ALBEDOS, albedo_de00, model_fields
    from grassd.sim.scene import RenderSettings

    captured = load_manifest(sage[camera] / "capture.toml")
    assert captured.sensitivities is not None
    lighting = captured.light.lighting()
    settings = RenderSettings(samples=4096, replicates=4)
    true = replace(captured, pixel=model_fields(SAGE))
    through, colours = {}, {}
    for how, m in (("camera", true), ("correction", replace(true, sensitivities=None))):
        v = validate_capture(m, renderer=renderer, settings=settings, lighting=lighting,
                             layouts=4)
        colour = [float(delta_E(c.real_lab, c.sim_lab, method="CIE 2000").mean())
                  for c in v.viewpoints]
        through[how], colours[how] = v, float(np.mean(colour))
        print(f"{camera} through the {how}: Frechet "
              f"{[round(c.frechet, 2) for c in v.viewpoints]}, colour {np.round(colour, 2)}")
    cam, cor = through["camera"], through["correction"]
    assert cam.chain == "camera" and cor.chain == cor.ccm.form
    assert max(c.frechet for c in cam.viewpoints) <= MEASURED_FRECHET
    assert colours["camera"] <= colours["correction"] * COLOUR_RATIO[camera] + 0.15
    fit = fit_capture(captured, holdout=[SAGE_VIEWS[-1]], renderer=renderer, lighting=lighting)
    assert fit.chain == "camera"
    de = {a: albedo_de00(fit.pixel[a], getattr(SAGE, a)) for a in ALBEDOS}
    held = next(vp for vp in fit.viewpoints if vp.held_out)
    print(f"{camera} fit: {de}; held out {held.fitted.frechet:.2f} "
          f"(true {cam.viewpoints[-1].frechet:.2f})")
    assert de["yellow_srgb"] <= 2.0 and de["green_srgb"] <= 2.0  # the goals
    assert de["base_srgb"] <= MEASURED_BASE
    assert held.fitted.frechet <= MEASURED_HELD_OUT


#: The true materials' worst Frechet distance through the camera, as measured with margin
#: (0.56 Nikon, 0.81 Sigma, at (200, 0.8, 90); the goal is 0.6).
MEASURED_FRECHET = 0.9
#: The fitted base's CIEDE2000 from the truth (4.00 Nikon, 4.75 Sigma; the goal is 4) and the
#: held-out view's Frechet distance (0.68 Nikon against a goal of 0.64, 0.58 Sigma against 0.5).
MEASURED_BASE = 5.25
MEASURED_HELD_OUT = 0.8
#: The camera's mean colour error at most this share of the correction's (plus 0.15): the
#: Nikon's measured 0.76 against 0.63 (both at the layout's floor), the Sigma's 0.82 against
#: 2.33.
COLOUR_RATIO = {"nikon-d5100": 1.0, "sigma-sdmerrill": 0.5}


#: A violet-blue grass of its own over a mauve soil in a forest's shade (not the bench's
#: pixels): saturated, so its spectra are far from flat where the light has its energy.
VIOLET = PixelSpec(yellow_srgb=(215.0, 200.0, 160.0), green_srgb=(120.0, 95.0, 200.0),
                   base_srgb=(130.0, 100.0, 120.0), layout_seed=613)


@pytest.mark.long
def test_spectral_transport_reads_the_world_as_the_spectral_renderer_does(tmp_path, renderer):
    """The daemon's characteristic of a pixel against Mitsuba's spectral path tracer read by
    the CIE observer, for the same tuft layout, each normalised by its own white card. RGB
    transport misses the absolute colour and the OGCD by what the spectra make of
    interreflections. Spectral transport (the trace plus the difference on recorded paths)
    comes within both renderers' noise (docs/calibration.md measures both)."""
    from colour import delta_E

    from grassd.calib.colour_spaces import (
        M_XYZ_TO_REC709,
        prophoto_to_lab,
        rec709_to_prophoto,
    )
    from grassd.daemon.core.calibration.simulation import simulate_curve, white_radiance
    from grassd.daemon.core.calibration.transport import SpectralTransport
    from grassd.rigs.spectral_world import observed_quads
    from grassd.sim.hdri import downsample, load_hdri, write_exr
    from grassd.sim.light_input import LightInput
    from grassd.sim.scene import RenderSettings

    hdri = Path(__file__).resolve().parents[3] / "shared" / "hdri" / "forest.exr"
    if not hdri.exists():
        pytest.skip(f"{hdri} not present (CI provides ../shared beside the clone)")
    write_exr(tmp_path / "env.exr", downsample(load_hdri(hdri), 4))
    lighting = LightInput(tmp_path / "env.exr", 4000.0).lighting()
    display, vp, x = DisplaySpec(VIOLET), Viewpoint(170, 2, 0), np.array([0.0, 10.0, 20.0])
    quads, white_xyz = observed_quads(tmp_path / "scenes", display, lighting, vp, x)

    def lab(rgb, white):
        return prophoto_to_lab(rec709_to_prophoto(np.clip(rgb / white, 0.0, None)))

    truth = lab(quads @ M_XYZ_TO_REC709.T, M_XYZ_TO_REC709 @ white_xyz)
    settings = RenderSettings(samples=16384, replicates=16, seed=3)
    found = {}
    for name, how in (("rgb", None), ("spectral", SpectralTransport.of(display, lighting, 16))):
        c = simulate_curve(renderer, display, lighting, vp, x, settings, spectral=how)
        ours = lab(c.rgb_linear, white_radiance(lighting))
        found[name] = (delta_E(ours, truth).max(),
                       np.abs(c.ogcd - delta_E(truth[:1], truth)).max())
    print(found)
    assert found["spectral"][0] <= 0.6 and found["spectral"][1] <= 0.3, found
    assert found["rgb"][0] >= 2 * found["spectral"][0], found
    assert found["rgb"][1] >= found["spectral"][1] + 0.2, found
