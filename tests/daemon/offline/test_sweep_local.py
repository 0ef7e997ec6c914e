"""``grassd sweep`` on local worker processes: tidy table, determinism, resume, CLI, errors."""

from __future__ import annotations

import json
import sqlite3

import numpy as np
import pytest
from click.testing import CliRunner

from grassd.daemon.offline.sweep import (
    Condition,
    SweepError,
    SweepSpec,
    conditions,
    light_condition,
    parse_pixel_option,
    read_results,
    run_sweep,
    summarise,
)

SITE = dict(latitude=35.0, longitude=139.0, date="2026-06-21", timezone="Asia/Tokyo")
SPEC = SweepSpec(lengths_mm=(0.0, 10.0, 20.0), samples=256, replicates=4, **SITE)


@pytest.fixture(scope="module")
def sky(tmp_path_factory):
    """A real EXR sky panorama (brighter above the horizon)."""
    from grassd.sim.hdri import write_exr

    env = np.ones((32, 64, 3), np.float32)
    env[:16] *= 2.0
    env[:16, :, 2] *= 1.3  # bluish sky
    path = tmp_path_factory.mktemp("hdri") / "sky.exr"
    write_exr(path, env)
    return str(path)


def _conds(sky):
    return conditions([sky], ["05:00", "09:00", "12:00", "19:30"], [(170, 2, 0), (160, 3, 60)],
                      [("default", ()), ("splay10", (("splay_deg", 10.0),))])


@pytest.fixture(scope="module")
def full(sky, tmp_path_factory):
    out = tmp_path_factory.mktemp("full")
    summary = run_sweep(SPEC, _conds(sky), out, workers=2)
    return out, summary


def test_light_through_the_day(sky):
    noon = light_condition(SPEC, "12:00", sky)
    morning = light_condition(SPEC, "09:00", sky)
    night = light_condition(SPEC, "19:30", sky)
    assert noon.sun_elevation_deg > morning.sun_elevation_deg > 3 > night.sun_elevation_deg
    assert noon.sun_lux > morning.sun_lux > 0 and night.sun_lux == 0
    assert 60000 < noon.ambient_lux + noon.sun_lux < 130000  # clear summer noon
    assert night.ambient_lux == SPEC.night_lux
    assert 150 < noon.sun_azimuth_deg < 210  # the sun is south at noon in Tokyo
    fixed = light_condition(SPEC, "", sky)
    assert fixed.sun_azimuth_deg is None and fixed.ambient_lux == SPEC.lux


def test_tidy_table_holds_every_condition_and_length(full, sky):
    out, summary = full
    conds = _conds(sky)
    assert summary.total == summary.computed == 16 and summary.skipped == 0
    rows = read_results(out / "sweep.sqlite")
    assert len(rows) == 16 * 3
    assert {r["key"] for r in rows} == {c.key(SPEC) for c in conds}
    assert len({r["worker"] for r in rows}) == 2  # both local processes worked
    for r in rows:
        if r["length_mm"] == 0.0:
            assert r["ogcd"] == 0.0
    db = sqlite3.connect(out / "sweep.sqlite")
    n_cond = db.execute("SELECT COUNT(*) FROM conditions").fetchone()[0]
    assert n_cond == 16
    by_key = {c.key(SPEC): c for c in conds}
    for key, seed, pixel in db.execute("SELECT key, seed, pixel FROM conditions"):
        assert seed == by_key[key].seed(SPEC) and pixel == by_key[key].pixel
    # the outputs the summary promises
    doc = json.loads((out / "summary.json").read_text())
    assert doc["conditions"] == 16 and len(doc["worst_viewpoints"]) == 2
    assert doc["worst_viewpoints"][0]["min_ogcd_range"] <= doc["worst_viewpoints"][1][
        "min_ogcd_range"]
    assert (out / "summary.png").stat().st_size > 20000


def test_stored_task_equals_a_direct_render_bit_for_bit(full, sky, renderer):
    """A worker process's stored result equals this process's render with the task's seed."""
    from grassd.daemon.core.calibration.simulation import simulate_curve
    from grassd.sim.lighting import build_lighting
    from grassd.sim.scene import DisplaySpec, PixelSpec, RenderSettings, Viewpoint

    out, _ = full
    cond = _conds(sky)[7]  # 09:00, (160, 3, 60), splay 10 deg
    assert cond.pixel == "splay10"
    light = light_condition(SPEC, cond.time, sky)
    lighting = build_lighting(sky, light.ambient_lux, sun_lux=light.sun_lux,
                              sun_azimuth_deg=light.sun_azimuth_deg,
                              sun_elevation_deg=light.sun_elevation_deg)
    settings = RenderSettings(samples=256, replicates=4, seed=cond.seed(SPEC))
    curve = simulate_curve(renderer, DisplaySpec(PixelSpec(splay_deg=10.0)), lighting,
                           Viewpoint(*cond.view), np.array(SPEC.lengths_mm), settings)
    stored = [r for r in read_results(out / "sweep.sqlite") if r["key"] == cond.key(SPEC)]
    assert [r["ogcd"] for r in stored] == curve.ogcd.tolist()
    assert [r["L"] for r in stored] == curve.lab[:, 0].tolist()
    assert [r["ogcd_stderr"] for r in stored] == curve.ogcd_stderr.tolist()


def test_resume_recomputes_only_what_is_missing(full, sky, tmp_path):
    import shutil

    out, _ = full
    shutil.copy(out / "sweep.sqlite", tmp_path / "sweep.sqlite")
    conds = _conds(sky)
    lost = [c.key(SPEC) for c in conds[3:8]]
    db = sqlite3.connect(tmp_path / "sweep.sqlite")
    with db:
        db.executemany("DELETE FROM results WHERE key = ?", [(k,) for k in lost])
    db.close()
    before = {r["key"]: r["worker"] for r in read_results(tmp_path / "sweep.sqlite")}
    summary = run_sweep(SPEC, conds, tmp_path, workers=1, plots=False)
    assert (summary.skipped, summary.computed) == (11, 5)
    after = read_results(tmp_path / "sweep.sqlite")
    assert {r["key"]: r["worker"] for r in after if r["key"] in before} == before
    assert read_results(tmp_path / "sweep.sqlite", run_columns=False) == \
        read_results(out / "sweep.sqlite", run_columns=False)
    again = run_sweep(SPEC, conds, tmp_path, workers=1, plots=False)
    assert (again.skipped, again.computed, again.executor) == (16, 0, "nothing to do")


def test_other_settings_refuse_to_resume_unless_restarted(full, sky, tmp_path):
    import shutil

    out, _ = full
    shutil.copy(out / "sweep.sqlite", tmp_path / "sweep.sqlite")
    other = SweepSpec(lengths_mm=(0.0, 10.0, 20.0), samples=512, replicates=4, **SITE)
    conds = _conds(sky)[:1]
    with pytest.raises(SweepError, match="other settings"):
        run_sweep(other, conds, tmp_path, workers=1, plots=False)
    s = run_sweep(other, conds, tmp_path, workers=1, plots=False, restart=True)
    assert s.computed == 1 and len(read_results(tmp_path / "sweep.sqlite")) == 3


def test_spec_errors(sky, tmp_path):
    with pytest.raises(SweepError, match="latitude"):
        run_sweep(SweepSpec(lengths_mm=(0, 10, 20)), conditions([sky], ["12:00"], [(170, 2, 0)]),
                  tmp_path)
    with pytest.raises(SweepError, match="HH:MM"):
        run_sweep(SPEC, conditions([sky], ["noon"], [(170, 2, 0)]), tmp_path)
    with pytest.raises(SweepError, match="does not exist"):
        run_sweep(SPEC, conditions([str(tmp_path / "no.exr")], [], [(170, 2, 0)]), tmp_path)
    with pytest.raises(SweepError, match="same condition twice"):
        run_sweep(SPEC, [Condition(sky, "", (170, 2, 0))] * 2, tmp_path)
    with pytest.raises(SweepError, match="FIELD=NUMBER"):
        parse_pixel_option("x:nonsense=3")
    assert parse_pixel_option("tall:green_max_mm=25,splay_deg=5") == (
        "tall", (("green_max_mm", 25.0), ("splay_deg", 5.0)))


def test_summary_flags_low_contrast():
    rows = [dict(h_cm=170.0, d_m=2.0, theta_deg=0.0, ogcd_range=r, linearity_r2=0.9, hdri="a",
                 time=t, pixel="p", sun_elevation_deg=e, ambient_lux=100.0, sun_lux=0.0)
            for r, t, e in ((12.0, "12:00", 70.0), (3.0, "19:00", -2.0))]
    doc = summarise(rows, contrast_threshold=5.0)
    assert [c["time"] for c in doc["low_contrast"]] == ["19:00"]
    assert doc["worst_viewpoints"][0]["min_ogcd_range"] == 3.0


def test_cli_runs_resumes_and_reports(sky, tmp_path):
    from grassd.daemon.cli.main import main

    args = ["sweep", "--hdri", sky, "--view", "170,2,0", "--view", "170,2,75", "--lengths",
            "0:20:10", "--samples", "256", "--replicates", "4", "--lux", "15000",
            "--workers", "1", "--out", str(tmp_path / "o")]
    res = CliRunner().invoke(main, args)
    assert res.exit_code == 0, res.output
    assert "2 tasks: 0 already stored, 2 computed" in res.output
    assert "worst viewpoint" in res.output
    res = CliRunner().invoke(main, args)
    assert "2 tasks: 2 already stored, 0 computed" in res.output
    bad = CliRunner().invoke(main, args[:-2] + ["--time", "12:00", "--out", str(tmp_path / "p")])
    assert bad.exit_code == 2 and "--latitude" in bad.output
