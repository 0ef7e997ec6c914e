"""grassd validate against virtual worlds: the real renderer draws a "real" pixel, the virtual
camera photographs it into DNGs, validate develops them with rawpy and compares them with a
fresh simulation of the model. A zero-difference world must agree (Frechet < 0.3); a world that
differs on purpose must show the difference the renderer itself predicts for it."""

from __future__ import annotations

import numpy as np
import pytest
from colour import delta_E

from grassd.calib.ccm import CCM_FORMS
from grassd.calib.characteristic import Characteristic
from grassd.calib.checker_photo import virtual_checker
from grassd.calib.compare import frechet_characteristics, max_ogcd_error
from grassd.calib.ogcd import ogcd_from_samples
from grassd.calib.virtual_camera import VirtualCamera
from grassd.daemon.core.calibration.simulation import white_radiance
from grassd.daemon.offline.validate import (
    load_manifest,
    max_error_at,
    validate_capture,
)
from grassd.daemon.offline.virtual_capture import capture_world
from grassd.sim.light_input import LightInput

LENGTHS = np.arange(0.0, 20.1, 4.0)
PHOTO = {"width": 128, "spp": 16}


@pytest.fixture(scope="module")
def world(renderer, shared_hdri):
    from grassd.sim.scene import RenderSettings

    light = LightInput(shared_hdri("interior"), 500.0)
    return {"light": light, "lighting": light.lighting(), "cache": {},
            "settings": RenderSettings(samples=16384, replicates=4)}


def _validate(tmp_path, renderer, world, views, *, real_pixel=None, camera=None):
    capture_world(tmp_path, world["light"], views, LENGTHS, real_pixel=real_pixel,
                  camera=camera, renderer=renderer, lighting=world["lighting"],
                  cache=world["cache"], **PHOTO)
    return validate_capture(load_manifest(tmp_path), renderer=renderer,
                            settings=world["settings"], lighting=world["lighting"])


def _truth(renderer, world, result, pixel, viewpoint):
    """The characteristic the renderer itself gives the photographed pixel, through the same
    colour chain (white card, checker exposure, the capture's M): what validate should measure
    as the real curve."""
    from grassd.calib.charts import get_chart
    from grassd.sim.scene import DisplaySpec, RenderSettings, Viewpoint

    _, s = virtual_checker(get_chart("spydercheckr-24"))
    m = renderer.characteristic(DisplaySpec(pixel), world["lighting"], Viewpoint(*viewpoint),
                                LENGTHS, RenderSettings(samples=16384, replicates=4, seed=7))
    reps = m.rgb_replicates / white_radiance(world["lighting"]) * s
    res = ogcd_from_samples(reps, space="rec709", ccm=result.ccm)
    return Characteristic(LENGTHS, res.ogcd)


def test_zero_difference_world_agrees(tmp_path, renderer, world):
    res = _validate(tmp_path, renderer, world, [(170.0, 2.0, 0.0), (160.0, 2.0, 60.0)])
    assert [v.reference for v in res.viewpoints] == [True, False]
    assert res.ccm.mean_de00 < 0.5  # camera noise only: the 3x3 is exact for a linear camera
    # the form of least leave-one-out error, and the report prints that error, not the fit's
    report = res.to_json()["ccm"]
    assert report["form"] == res.ccm.candidates[0].form == res.ccm.form
    assert len(res.ccm.candidates) == len(CCM_FORMS)
    assert (report["mean_de00"], report["max_de00"]) == (res.ccm.loo_mean_de00,
                                                         res.ccm.loo_max_de00)
    assert report["fit_mean_de00"] == res.ccm.mean_de00 < res.ccm.loo_mean_de00
    for v in res.viewpoints:
        print(f"zero-difference {v.label}: Frechet {v.frechet:.3f}, max error "
              f"{v.max_error:.3f}, Lab dE00 max {delta_E(v.real_lab, v.sim_lab).max():.2f}")
        assert v.frechet < 0.3, (v.label, v.real.ogcd, v.sim.ogcd)
        # not only the differences: the absolute colours agree too
        assert delta_E(v.real_lab, v.sim_lab).max() < 1.5
        assert v.max_error < 0.3
        assert abs(v.real_range - v.sim_range) < 0.3
        assert v.max_error == pytest.approx(max_ogcd_error(v.real, v.sim))
        assert 8.0 < v.real_range < 20.0  # a real S-curve, not two flat lines agreeing
        cal = v.calibration
        assert cal.r2_after_real > 0.999 and cal.r2_after_sim > 0.995
        assert cal.r2_before < cal.r2_after_sim
    doc = res.to_json()
    assert doc["reference_viewpoint"] == [170.0, 2.0, 0.0]
    assert len(doc["viewpoints"][0]["real_ogcd"]) == len(LENGTHS)


def test_splayed_blades_measured_as_the_renderer_predicts(tmp_path, renderer, world):
    from grassd.sim.scene import PixelSpec

    real = PixelSpec(splay_deg=20.0)
    vp = (160.0, 2.0, 90.0)
    res = _validate(tmp_path, renderer, world, [vp], real_pixel=real)
    v = res.viewpoints[0]
    truth = _truth(renderer, world, res, real, vp)
    # validate's real curve is the photographed world's own characteristic ...
    assert np.abs(v.real.ogcd - truth.ogcd).max() < 0.3
    # ... so the error it reports is the model error: splayed blades cover more yellow
    expected = frechet_characteristics(truth, v.sim)
    assert v.frechet == pytest.approx(expected, abs=0.3)
    print(f"splay 20 deg {v.label}: Frechet {v.frechet:.2f} (renderer's own: {expected:.2f}), "
          f"ranges real {v.real_range:.2f} sim {v.sim_range:.2f}")
    assert v.frechet > 2.0
    assert v.real_range > v.sim_range + 2.0  # sign: the real pixel gets greener
    err, at = max_error_at(v.real, v.sim)
    assert err == v.max_error and at >= 12.0  # where the blades are long


def test_albedo_error_and_noisy_camera(tmp_path, renderer, world):
    from grassd.sim.scene import PixelSpec

    real = PixelSpec(green_srgb=(30.0, 90.0, 20.0))  # darker, more saturated green than modelled
    vp = (170.0, 2.0, 0.0)
    res = _validate(tmp_path / "albedo", renderer, world, [vp], real_pixel=real)
    v = res.viewpoints[0]
    truth = _truth(renderer, world, res, real, vp)
    assert np.abs(v.real.ogcd - truth.ogcd).max() < 0.3
    assert v.frechet == pytest.approx(frechet_characteristics(truth, v.sim), abs=0.3)
    assert v.real_range - v.sim_range == pytest.approx(
        float(truth.ogcd.max() - v.sim.ogcd.max()), abs=0.3)
    print(f"albedo error {v.label}: Frechet {v.frechet:.2f} (renderer's own: "
          f"{frechet_characteristics(truth, v.sim):.2f}), ranges real {v.real_range:.2f} "
          f"sim {v.sim_range:.2f}")
    assert v.real_range > v.sim_range + 0.3  # sign: the real pixel shows more contrast

    # a noisy 12-bit camera on the zero-difference world: noise averages out over the quad
    noisy = VirtualCamera(bits=12, full_well_e=6000.0, read_noise_e=10.0)
    res_n = _validate(tmp_path / "noisy", renderer, world, [vp], camera=noisy)
    vn = res_n.viewpoints[0]
    assert res_n.real.camera["white_level"] == 4095
    print("noisy camera", vn.frechet, vn.max_error, res_n.ccm.mean_de00)
    assert vn.frechet < 0.3


def test_repeated_trials_give_repeatability(tmp_path, renderer, world):
    """Three trials at the reference viewpoint, the blades resting differently in each: one
    simulation serves all three, and the spread of the real OGCD is the repeatability."""
    capture_world(tmp_path, world["light"], [(170.0, 2.0, 0.0)], LENGTHS, renderer=renderer,
                  lighting=world["lighting"], extra_trials=2, width=96, spp=8)
    m = load_manifest(tmp_path)
    assert len(m.series) == 3 and [s.reference for s in m.series] == [True, False, False]
    res = validate_capture(m, renderer=renderer, settings=world["settings"],
                           lighting=world["lighting"])
    rep = res.repeatability["(170, 2, 0)"]
    stacked = np.stack([v.real.ogcd for v in res.viewpoints])
    assert rep["trials"] == 3
    assert rep["std_ogcd"] == pytest.approx(stacked.std(axis=0, ddof=1).tolist())
    print(f"repeatability over 3 blade layouts: mean OGCD std {rep['mean_std_ogcd']:.3f}")
    assert 0.01 < rep["mean_std_ogcd"] < 1.0  # the layouts differ, the pixel is the same
    assert all(np.array_equal(v.sim.ogcd, res.viewpoints[0].sim.ogcd) for v in res.viewpoints)
    assert res.to_json()["repeatability"]["(170, 2, 0)"]["trials"] == 3
