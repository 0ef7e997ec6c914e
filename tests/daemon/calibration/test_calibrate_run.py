"""Calibration runs with the real renderer (Taichi, CPU) on the bundled default site HDRI."""

from __future__ import annotations

import json
from dataclasses import replace
from datetime import UTC, datetime

import numpy as np
import pytest
from daemon_harness import HEAD, SITE

from grassd.calib.ccm import ColourCorrection
from grassd.calib.charts import get_chart
from grassd.calib.colour_spaces import prophoto_to_xyz, xyz_d50_to_d65
from grassd.calib.dng import DngCamera, write_linear_dng
from grassd.calib.errors import ClippedCheckerError
from grassd.calib.exposure import normalise_exposure
from grassd.calib.regions import apply_homography, homography
from grassd.daemon.core.calibration.calibrate import Calibrator, init_backend
from grassd.daemon.core.calibration.checks import check_shape, check_table
from grassd.daemon.core.config.settings import parse_config
from grassd.daemon.core.errors import CalibrationRejected, ConfigError
from grassd.daemon.core.store.atomic import atomic_save_figure, atomic_write_json
from grassd.daemon.core.store.manifest import CheckerPhoto
from grassd.sim.light_input import LightInput

TINY = HEAD + """[display]
rows = 3
cols = 3
[[controllers]]
port = "/dev/null"
[[viewpoints]]
h_cm = 170
d_m = 2
weight = 2
[[viewpoints]]
h_cm = 160
d_m = 2
theta_deg = 30
[light]
inbox = "inbox"
[simulation]
samples = 144
seed = 3
lengths = 9
[calibration]
check_levels = 9
max_rounds = 2
replicates = 4
"""


@pytest.fixture(scope="module")
def cfg(tmp_path_factory):
    c = parse_config(TINY, base_dir=tmp_path_factory.mktemp("cal"))
    init_backend(c)
    return c


def light(**kw) -> LightInput:
    base = dict(hdri=SITE, ambient_lux=8000.0, timestamp=datetime(2026, 6, 21, 10, tzinfo=UTC))
    base.update(kw)
    return LightInput(**base)


def test_shape_check():
    x = np.linspace(0, 20, 11)
    good = np.concatenate([[0, 0.2], np.linspace(1, 20, 9)])
    stats = check_shape(x, good, np.full(11, 0.1), 0.6)
    assert stats["wild_steps"] == 0 and stats["flat_fraction"] < 0.2
    flat = np.concatenate([np.zeros(8), [5, 10, 15]])
    with pytest.raises(CalibrationRejected, match="flat over 70%"):
        check_shape(x, flat, np.full(11, 0.1), 0.6)
    wild = good.copy()
    wild[6] = 2.0  # a 10 dE00 drop
    with pytest.raises(CalibrationRejected, match="wild step"):
        check_shape(x, wild, np.full(11, 0.1), 0.6)


def test_shape_check_reads_the_steps_own_errors():
    """Errors that move the whole curve (a tuft layout) are large per length but small per
    step: with the steps' own errors the same curve is no longer called flat."""
    x = np.linspace(0.0, 20.0, 11)
    y = np.linspace(0.0, 5.0, 11)  # steps of 0.5 dE00
    se = np.full(11, 0.3)  # hypot 0.42: every step within 2 sigma
    with pytest.raises(CalibrationRejected, match="flat"):
        check_shape(x, y, se, 0.6)
    stats = check_shape(x, y, se, 0.6, step_stderr=np.full(10, 0.05))
    assert stats["flat_fraction"] == 0.0
    # unsorted lengths: the steps' errors cannot be matched, so they are not used
    with pytest.raises(CalibrationRejected, match="flat"):
        check_shape(x[::-1], y[::-1], se, 0.6, step_stderr=np.full(10, 0.05))


def test_table_checks():
    t = np.linspace(0, 20000, 256).astype(np.uint16)
    assert check_table(t, 20.0, None, 3.0, False) is None
    assert check_table(t, 20.0, t + 0, 3.0, False) == 0
    bad = t.copy()
    bad[100] = 0
    with pytest.raises(CalibrationRejected, match="not monotone"):
        check_table(bad, 20.0, None, 3.0, False)
    with pytest.raises(CalibrationRejected, match="range"):
        check_table(t, 15.0, None, 3.0, False)
    shifted = np.clip(t.astype(int) + 4000, 0, 20000).astype(np.uint16)
    with pytest.raises(CalibrationRejected, match="wild jump.*--force"):
        check_table(shifted, 20.0, t, 3.0, False)
    assert check_table(shifted, 20.0, t, 3.0, True) == 4000
    with pytest.raises(CalibrationRejected, match="shape"):
        check_table(t[:255], 20.0, None, 3.0, False)


def test_run_produces_linear_table_and_report(cfg, tmp_path):
    res = Calibrator(cfg).run(light(), progress=lambda s: None)
    t = res.lengths_um
    assert t.shape == (256,) and t.dtype == np.uint16
    assert t[0] == 0 and np.all(np.diff(t.astype(int)) >= 0) and t[-1] <= 20000
    m = res.metrics()
    print(f"\nR^2 before {m['r2_before']:.4f}, closed loop {m['r2_closed_loop']:.5f}, "
          f"max dev {m['max_dev_de00']:.3f} dE00 in {m['rounds']} round(s), OGCD range "
          f"{m['ogcd_range_de00']:.2f}, mean stderr {m['mean_ogcd_stderr_de00']:.3f}, "
          f"{m['seconds']['total']:.1f} s")
    assert m["r2_closed_loop"] > m["r2_before"]
    assert m["r2_closed_loop"] >= 0.99
    assert 1 <= m["rounds"] <= 2 and m["ogcd_range_de00"] > 5
    assert len(res.curves) == 2 and res.ccm is None
    # the report is valid JSON and the plot a PNG, both written atomically
    rep = atomic_write_json(tmp_path / "r.json", res.report())
    assert json.loads(rep.read_text())["table_um"] == t.tolist()
    png = atomic_save_figure(tmp_path / "p.png", res.figure())
    assert png.read_bytes()[:4] == b"\x89PNG"
    # reproducible with the same seed
    again = Calibrator(cfg).run(light())
    assert np.array_equal(again.lengths_um, t)
    # a previous table far away is a wild jump unless forced
    far = np.full(256, 20000, np.uint16)
    far[0] = 0
    with pytest.raises(CalibrationRejected, match="wild jump"):
        Calibrator(cfg).run(light(), previous_um=far)
    forced = Calibrator(cfg).run(light(), previous_um=far, force=True)
    assert forced.max_step_um > 3000


def test_sun_from_site_and_time(cfg):
    lt = Calibrator(cfg).lighting(light(sun_lux=20000.0))
    assert lt.sun_direction is not None and lt.sun_lux == pytest.approx(20000.0)
    assert any("sun direction from site and time" in n for n in lt.notes)
    night = Calibrator(cfg).lighting(light(sun_lux=20000.0,
                                           timestamp=datetime(2026, 6, 21, 23, tzinfo=UTC)))
    assert night.sun_direction is None and any("below the horizon" in n for n in night.notes)


def test_site_camera_orientation_from_config(tmp_path):
    """[light] hdri_flip / hdri_rotation_deg orient the bundle's panorama before lighting."""
    from grassd.sim.hdri import load_hdri
    from grassd.sim.lighting import orient_env

    oriented = parse_config(TINY.replace('inbox = "inbox"', 'inbox = "inbox"\nhdri_flip = true'
                                         '\nhdri_rotation_deg = 90'), base_dir=tmp_path)
    assert oriented.light.hdri_flip and oriented.light.hdri_rotation_deg == 90.0
    plain = parse_config(TINY, base_dir=tmp_path)
    a = Calibrator(plain).lighting(light())
    b = Calibrator(oriented).lighting(light())
    assert b.flipped and b.rotation_deg == 90.0 and not a.flipped
    want = orient_env(load_hdri(SITE), rotation_deg=90.0, flip=True)
    np.testing.assert_allclose(b.env, want * b.env_scale, rtol=1e-5)
    assert not np.allclose(a.env, b.env)
    with pytest.raises(ConfigError, match="hdri_rotation_deg"):
        parse_config(TINY.replace('inbox = "inbox"', 'inbox = "inbox"\nhdri_rotation_deg = 400'),
                     base_dir=tmp_path)


def _chart_image(prophoto, corners, h=200, w=300):
    hinv = homography(corners, [(0, 0), (1, 0), (1, 1), (0, 1)])
    yy, xx = np.mgrid[0:h, 0:w]
    uv = apply_homography(hinv, np.stack([xx + 0.5, yy + 0.5], axis=-1))
    u, v = uv[..., 0], uv[..., 1]
    col, row = np.floor(u * 6).astype(int), np.floor(v * 4).astype(int)
    inside = ((u >= 0) & (u < 1) & (v >= 0) & (v < 1) & (np.abs(u * 6 - col - 0.5) < 0.4)
              & (np.abs(v * 4 - row - 0.5) < 0.4))
    img = np.full((h, w, 3), 0.05)
    img[inside] = prophoto[(np.clip(row, 0, 3) * 6 + np.clip(col, 0, 5))[inside]]
    return img


def _checker_dng(cal: Calibrator, path, exposure: float = 0.8):
    """A real DNG of a chart whose colours went through a known 3x3 cross-talk; (path,
    corners, the cross-talk)."""
    lt = cal.lighting(light())
    chart = get_chart("spydercheckr-24")
    grey = chart.grey_index()
    from grassd.calib.colour_spaces import rec709_to_prophoto, xyz_to_rec709

    albedo = np.clip(xyz_to_rec709(prophoto_to_xyz(chart.prophoto())), 0, None)
    virtual = normalise_exposure(rec709_to_prophoto(albedo * cal.white_radiance(lt)),
                                 rec709_to_prophoto(albedo * cal.white_radiance(lt))[grey])
    m_true = np.array([[0.92, 0.06, 0.02], [0.03, 0.95, 0.02], [0.01, 0.07, 0.92]])
    real = virtual @ m_true.T * 0.5
    corners = np.array([(40.0, 30.0), (260.0, 45.0), (250.0, 175.0), (30.0, 165.0)])
    xyz = xyz_d50_to_d65(prophoto_to_xyz(_chart_image(real, corners)))
    dng = write_linear_dng(path, xyz, DngCamera(), exposure=exposure)
    return dng, tuple(map(tuple, corners)), m_true


def test_checker_raw_gives_ccm(cfg, tmp_path):
    """The paper's 3x3 fitted to a real DNG of a chart with known cross-talk gives it back;
    its report prints the leave-one-out error, not the fitting residual."""
    cal = Calibrator(replace(cfg, calibration=replace(cfg.calibration, ccm="3x3")))
    dng, corners, m_true = _checker_dng(cal, tmp_path / "chart.dng")
    ccm = cal.fit_checker_ccm(CheckerPhoto(dng, corners))
    print(f"\nCCM from DNG: fit mean {ccm.mean_de00:.3f}, max {ccm.max_de00:.3f} dE00; "
          f"leave-one-out {ccm.loo_mean_de00:.3f} / {ccm.loo_max_de00:.3f}")
    assert ccm.form == "3x3" and ccm.mean_de00 < 1.0
    assert ccm.reported_de00 == (ccm.loo_mean_de00, ccm.loo_max_de00)
    assert ccm.loo_mean_de00 >= ccm.mean_de00  # a patch left out is predicted less well
    got = ccm.matrix / ccm.matrix.sum(axis=1, keepdims=True)
    want = m_true / m_true.sum(axis=1, keepdims=True)
    assert np.abs(got - want).max() < 0.05
    assert np.abs(got - np.eye(3)).max() > 0.03  # it is not the identity


def test_checker_raw_ccm_form_chosen_by_leave_one_out(cfg, tmp_path):
    """With ``ccm = "auto"`` (the default) every form is fitted and the one of lowest
    leave-one-out mean is kept; the metrics and report print its leave-one-out figures and
    the report lists every candidate."""
    assert cfg.calibration.ccm == "auto"
    cal = Calibrator(cfg)
    dng, corners, _ = _checker_dng(cal, tmp_path / "chart.dng")
    ccm = cal.fit_checker_ccm(CheckerPhoto(dng, corners))
    forms = [c.form for c in ccm.candidates]
    assert sorted(forms) == ["3x3", "root-polynomial-2", "root-polynomial-3"]
    assert ccm.form == forms[0]
    assert ccm.loo_mean_de00 == min(c.loo_mean_de00 for c in ccm.candidates)
    res = cal.run(light(), checker=CheckerPhoto(dng, corners))
    m, rep = res.metrics(), res.report()
    assert (m["ccm_source"], m["ccm_form"]) == ("bundle", res.ccm.form)
    assert (m["ccm_mean_de00"], m["ccm_max_de00"]) == pytest.approx(
        (res.ccm.loo_mean_de00, res.ccm.loo_max_de00))
    assert rep["ccm"]["fit_mean_de00"] == pytest.approx(res.ccm.mean_de00)
    assert [c["form"] for c in rep["ccm"]["candidates"]] == forms
    again = ColourCorrection.from_json(json.loads(json.dumps(res.ccm.to_json())))
    rgb = np.random.default_rng(1).uniform(0.05, 0.9, (16, 3))
    np.testing.assert_allclose(again.apply(rgb), res.ccm.apply(rgb), rtol=1e-12)


def test_clipped_checker_raw_refused_naming_the_patches(cfg, tmp_path):
    """A checker RAW exposed so that its light patches clip is refused (a clipped patch bends
    the correction), before any correction is fitted to it."""
    cal = Calibrator(cfg)
    dng, corners, _ = _checker_dng(cal, tmp_path / "bright.dng", exposure=4.0)
    with pytest.raises(ClippedCheckerError, match="A1"):
        cal.fit_checker_ccm(CheckerPhoto(dng, corners))


def test_run_with_previous_ccm_gives_json_metrics_and_report(cfg, tmp_path):
    """A run without a checker RAW reuses the last correction, which has no residuals: its
    metrics and report must still be valid JSON (the service writes both with
    allow_nan=False)."""
    res = Calibrator(cfg).run(light(), previous_ccm=ColourCorrection.from_json(
        np.eye(3).tolist()))
    assert res.ccm_source == "previous"
    m = res.metrics()
    assert m["ccm_mean_de00"] is None and m["ccm_max_de00"] is None
    rep = atomic_write_json(tmp_path / "r.json", {"metrics": m, **res.report()})
    assert json.loads(rep.read_text())["ccm"]["source"] == "previous"


def test_closed_loop_reports_progress_per_viewpoint(cfg):
    """The service's watchdog pings only while the main thread shows progress; the closed-loop
    re-simulation renders every viewpoint again, so it must report each one too."""
    seen: list[str] = []
    Calibrator(cfg).run(light(), progress=seen.append)
    loop = [s for s in seen if s.startswith("closed loop round 1")]
    assert len(loop) >= len(cfg.viewpoints), seen  # one report per trace
