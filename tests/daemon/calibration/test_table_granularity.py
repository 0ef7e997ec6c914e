"""The daemon honours [tables] granularity and [audience]: a 2 x 2 display driven by two
simulated controllers on real ptys (one bus each), low sample counts.

Checked: each controller is pushed its own table (per controller: (256,), per pixel: (2, 256))
and ends up reporting that table's CRC; history, status and the JSON report carry every
controller's CRC; an unplugged controller gets its own table on reconcile; the closed loop
re-simulates every pixel group and refines the tables that miss its target; an audience region
of one eye gives the tables of the equivalent viewpoint; Fleet.push takes a name -> table map;
`grassd calibrate --now` and `grassd status` (separate processes) show per-controller CRCs.
"""

from __future__ import annotations

import json
import time
from datetime import UTC, datetime
from pathlib import Path

import numpy as np
import pytest
from daemon_harness import DISPLAY_2X2 as BASE
from daemon_harness import POLICY, SITE
from daemon_harness import drop_midsummer as drop

from grassd.daemon.core.calibration.calibrate import Calibrator, init_backend
from grassd.daemon.core.config.settings import not_used_by_the_daemon, parse_config
from grassd.daemon.core.hardware.fleet import Fleet, table_checksum
from grassd.daemon.core.runtime.service import Service, collect_status
from grassd.rigs.simulated_site import SimulatedHardware
from grassd.sim.light_input import LightInput

AUDIENCE = """
[audience]
polygon = [[{x0}, {y0}], [{x1}, {y0}], [{x1}, {y1}], [{x0}, {y1}]]
h_cm = [{h0}, {h1}]
ground_samples = {g}
height_samples = 1
"""


def config(tmp_path: Path, extra: str):
    return parse_config(BASE + extra, base_dir=tmp_path)


@pytest.fixture
def rig(tmp_path):
    """(service, simulated hardware) for a config with ``extra`` appended."""
    made: list = []

    def make(extra: str) -> tuple[Service, SimulatedHardware]:
        sim = SimulatedHardware(config(tmp_path, extra), tmp_path / "hw")
        cfg = sim.start()
        made.append(sim)
        svc = Service(cfg, policy=POLICY)
        made.append(svc)
        init_backend(cfg)
        return svc, sim

    yield make
    for m in reversed(made):
        if isinstance(m, Service):
            m.shutdown()
        else:
            m.stop()


def devices(sim: SimulatedHardware, cfg) -> dict[str, object]:
    """Controller name -> its simulated device (one per bus, in config order)."""
    return {c.name: bus.controllers[0] for c, bus in zip(cfg.controllers, sim.buses, strict=True)}


def run_bundle(svc: Service, name: str = "b1") -> dict:
    drop(svc.cfg.light.inbox, name)
    [b] = svc.inbox.poll()
    out = svc.process_bundle(b)
    assert out.status == "ok", out
    return out


def test_controller_tables_pushed_and_reconciled_after_unplug(rig):
    svc, sim = rig('[tables]\ngranularity = "controller"\ncheck_groups = 0\n')
    names = [c.name for c in svc.cfg.controllers]
    t0 = time.monotonic()
    out = run_bundle(svc)
    first_run_s = time.monotonic() - t0
    crcs = out.committed.controller_crcs
    assert sorted(crcs) == sorted(names)
    assert crcs[names[0]] != crcs[names[1]]  # two controllers, two tables
    assert out.committed.table_crc not in crcs.values()  # the display-wide table is a third one
    for r in out.controllers:
        assert r.ok and r.pushed and r.table_crc == crcs[r.controller]
    stored = svc.history.run_tables(out.run_id)
    for name, dev in devices(sim, svc.cfg).items():
        assert stored[name].lengths_um.shape == (256,)
        assert stored[name].table_crc == crcs[name] == table_checksum(stored[name].lengths_um)
        np.testing.assert_array_equal(dev.active_table().ravel(), stored[name].lengths_um)
    reported = {c.name: (st.table_id, st.table_crc) for c, st, _ in svc.fleet.read_all()}
    assert reported == {n: (out.run_id, crc) for n, crc in crcs.items()}  # over the wire
    st = collect_status(svc.history, svc.cfg).to_json()
    assert st["health"] == "ok" and st["desired_table"]["per_controller"] == crcs
    assert {c["name"]: (c["desired_crc"], c["table_crc"], c["in_sync"])
            for c in st["controllers"]} == {n: (crcs[n], crcs[n], True) for n in names}
    report = json.loads(Path(out.committed.report).read_text())
    assert report["granularity"] == "controller" and report["table_source"] == "viewpoints"
    assert {k: v["table_crc"] for k, v in report["controller_tables"].items()} == crcs
    m = out.committed.metrics
    assert (m["tables"], m["check"], m["rounds"]) == (2, "closed loop", 1)
    # closed loop: the 4 pixels (4 geometry groups) re-simulated at 5 check levels each
    assert np.shape(report["closed_loop"]["ogcd_de00"]) == (4, 5)
    assert m["max_dev_de00"] == pytest.approx(max(report["closed_loop"]["max_dev_de00"]))
    assert 0.5 < m["r2_closed_loop"] <= 1.0

    # the second controller is unplugged during the next run: it keeps the old table, then
    # gets ITS table of the new run when it answers again
    # (down for three times as long as the first run took, so that it is still down when the
    # run pushes, however loaded the machine is)
    down_s = max(1.0, 3 * first_run_s)
    sim.buses[1].unplug(down_s=down_s)
    out2 = svc.scheduled_run("request")
    assert out2.status == "ok"
    crcs2 = out2.committed.controller_crcs
    assert [r.ok for r in out2.controllers] == [True, False]
    st = collect_status(svc.history, svc.cfg).to_json()
    bad = st["controllers"][1]["name"]
    assert st["health"].startswith(f"degraded: controller {bad} ")  # one of two is off
    deadline = time.monotonic() + down_s + 10
    while time.monotonic() < deadline:
        reports = svc.reconcile()
        if all(r.ok for r in reports):
            break
        time.sleep(0.2)
    back = {r.controller: r for r in reports}
    assert back[names[1]].ok and back[names[1]].pushed
    assert back[names[1]].table_id == out2.run_id
    assert back[names[1]].table_crc == crcs2[names[1]] != crcs2[names[0]]
    assert not back[names[0]].pushed  # it already held its own table: one status read
    own = svc.history.run_tables(out2.run_id)[names[1]].lengths_um
    np.testing.assert_array_equal(devices(sim, svc.cfg)[names[1]].active_table().ravel(), own)
    [rec] = [p for p in svc.history.pushes(out2.run_id) if p.kind == "reconcile"]
    assert (rec.controller, rec.ok, rec.table_crc) == (names[1], True, crcs2[names[1]])
    assert collect_status(svc.history, svc.cfg).to_json()["health"] == "ok"


def test_pixel_tables_one_row_per_pixel_on_each_controller(rig):
    svc, sim = rig('[tables]\ngranularity = "pixel"\ncheck_groups = 0\n')
    out = run_bundle(svc)
    crcs = out.committed.controller_crcs
    stored = svc.history.run_tables(out.run_id)
    assert len(set(crcs.values())) == 2
    for name, dev in devices(sim, svc.cfg).items():
        t = stored[name].lengths_um
        assert t.shape == (2, 256)  # the two pixels this controller drives
        assert not np.array_equal(t[0], t[1])  # different neighbours: different tables
        assert table_checksum(t) == crcs[name]
        np.testing.assert_array_equal(dev.active_table(), t)
    reported = {c.name: (st.table_id, st.table_crc) for c, st, _ in svc.fleet.read_all()}
    assert reported == {n: (out.run_id, crc) for n, crc in crcs.items()}  # over the wire
    assert [r.ok for r in out.controllers] == [True, True]
    assert collect_status(svc.history, svc.cfg).to_json()["health"] == "ok"
    assert out.committed.metrics["granularity"] == "pixel" and out.committed.metrics["tables"] == 4


def light() -> LightInput:
    return LightInput(hdri=SITE, ambient_lux=8000.0,
                      timestamp=datetime(2026, 6, 21, 10, tzinfo=UTC))


def test_audience_region_drives_the_tables(tmp_path):
    """A one-eye region at the viewpoint's world position gives (nearly) the viewpoint's
    controller tables; a wider region gives other ones; [audience] with granularity global
    gives one region table for every controller."""
    ctrl = '[tables]\ngranularity = "controller"\ncheck_groups = 0\n'
    one_eye = AUDIENCE.format(x0=-0.5, x1=0.5, y0=-2.5, y1=-1.5, h0=170, h1=170, g=1)
    wide = AUDIENCE.format(x0=-1.5, x1=1.5, y0=-4.0, y1=-1.5, h0=150, h1=180, g=4)
    cfg_v = config(tmp_path, ctrl)
    init_backend(cfg_v)
    by_view = Calibrator(cfg_v).run(light())
    by_eye = Calibrator(config(tmp_path, ctrl + one_eye)).run(light())
    by_region = Calibrator(config(tmp_path, ctrl + wide)).run(light())
    assert (by_view.source, by_eye.source) == ("viewpoints", "audience")
    assert by_eye.region["eyes"] == 1 and by_region.region["eyes"] == 6
    for name, t in by_view.controller_tables.items():
        # the same traces: the region optimum over one eye is the inverted characteristic
        diff = np.abs(by_eye.controller_tables[name].astype(int) - t.astype(int))
        assert diff.max() <= 2, (name, diff.max())
        far = np.abs(by_region.controller_tables[name].astype(int) - t.astype(int))
        assert far.max() > 500  # six eyes from 1.5 to 4 m away: another table (about 1.7 mm)
    # errors are measured on every pixel of a controller, for each eye, in both cases
    for key in ("max_fit_dev_de00", "max_dev_de00", "r2_closed_loop"):
        assert by_eye.metrics()[key] == pytest.approx(by_view.metrics()[key], abs=1e-6), key
    glob = Calibrator(config(tmp_path, wide)).run(light())
    assert (glob.granularity, glob.source, len(glob.units)) == ("global", "audience", 1)
    [crc] = set(glob.controller_crcs().values())
    assert crc == table_checksum(glob.lengths_um)
    assert not_used_by_the_daemon(cfg_v) == []
    notes = not_used_by_the_daemon(config(tmp_path, ctrl.replace(
        "check_groups", 'eye = "pixel"\ncheck_groups') + wide))
    assert len(notes) == 1 and "tables.eye" in notes[0]


def test_fleet_push_takes_a_table_per_controller(tmp_path):
    sim = SimulatedHardware(config(tmp_path, ""), tmp_path / "hw")
    cfg = sim.start()
    a = np.linspace(0, 20000, 256).astype(np.uint16)
    b = (np.linspace(0, 1, 256) ** 0.7 * 20000).astype(np.uint16)
    per_pixel = np.stack([a, b])
    n0, n1 = (c.name for c in cfg.controllers)
    try:
        with Fleet(cfg.controllers, policy=POLICY) as fleet:
            res = fleet.push({n0: a, n1: per_pixel}, table_id=5)
            assert [(r.ok, r.pushed) for r in res] == [(True, True), (True, True)]
            assert [r.table_crc for r in res] == [table_checksum(a), table_checksum(per_pixel)]
            np.testing.assert_array_equal(sim.buses[1].controllers[0].active_table(), per_pixel)
            again = fleet.reconcile({n0: a, n1: per_pixel}, table_id=5)
            assert [(r.ok, r.pushed) for r in again] == [(True, False), (True, False)]
            # same id, another table for n1 only: only n1 is pushed
            res = fleet.push({n0: a}, table_id=5, fallback=b)
            assert [(r.ok, r.pushed) for r in res] == [(True, False), (True, True)]
            assert res[1].table_crc == table_checksum(b)
            with pytest.raises(ValueError, match=n1):
                fleet.push({n0: a}, table_id=6)
            bad = fleet.push({n0: np.stack([a, a, a]), n1: b}, table_id=7)  # 3 rows, 2 pixels
            assert not bad[0].ok and "per-pixel tables must have shape (2, 256)" in bad[0].error
            assert bad[0].table_crc == table_checksum(a)  # its old table stays active
            assert bad[1].ok
    finally:
        sim.stop()


def test_one_shot_cli_pushes_pixel_tables_and_status_shows_them(tmp_path):
    """`grassd calibrate --now` (a separate process, real ptys) with granularity "pixel", then
    `grassd status`: every controller in sync with its own table's CRC."""
    import subprocess
    import sys

    grassd = str(Path(sys.executable).parent / "grassd")
    extra = '[tables]\ngranularity = "pixel"\ncheck_groups = 0\n'
    sim = SimulatedHardware(config(tmp_path, extra), tmp_path / "hw")
    sim.start()
    try:
        text = BASE + extra
        for old, new in sim.ports.items():
            text = text.replace(old, new)
        conf = tmp_path / "grassd.toml"
        conf.write_text(text)
        drop(tmp_path / "state" / "inbox", "b1")
        r = subprocess.run([grassd, "calibrate", "--now", "--json", "-", "--config", str(conf)],
                           capture_output=True, text=True, timeout=180)
        assert r.returncode == 0, r.stderr
        res = json.loads(r.stdout)
        crcs = res["controller_crcs"]
        assert len(set(crcs.values())) == 2 and res["metrics"]["granularity"] == "pixel"
        assert "4 pixel table(s) from viewpoints" in r.stderr
        on_wire = {c.name: table_checksum(bus.controllers[0].active_table())
                   for c, bus in zip(parse_config(text, base_dir=tmp_path).controllers,
                                     sim.buses, strict=True)}
        assert on_wire == crcs
        r = subprocess.run([grassd, "status", "--config", str(conf)], capture_output=True,
                           text=True, timeout=60)
        assert "health: ok" in r.stdout and "one per controller" in r.stdout, r.stdout
        for crc in crcs.values():
            assert f"own table crc {crc:#010x}), in sync" in r.stdout
    finally:
        sim.stop()


def test_history_keeps_tables_per_run_and_prunes_them_with_the_run(tmp_path):
    from grassd.daemon.core.store.history import History

    a = np.arange(256, dtype=np.uint16) * 70
    with History(tmp_path / "state.db") as h:
        ids = []
        for k in range(3):
            rid = h.start_run("request")
            tables = {"p#1": a + k, "p#2": np.stack([a, a + 2 * k])}
            h.record_run_tables(rid, tables, {n: table_checksum(t) for n, t in tables.items()})
            h.finish_run(rid, "ok", lengths_um=a, table_id=rid, table_crc=table_checksum(a))
            ids.append(rid)
        got = h.run_tables(ids[1])
        t2 = got["p#2"].lengths_um
        assert t2.shape == (2, 256) and t2.dtype == np.uint16
        np.testing.assert_array_equal(t2[1], a + 2)
        assert got["p#1"].table_crc == table_checksum(a + 1)
        assert h.prune_runs(1) == 2  # keeps the newest run only
        assert h.run_tables(ids[0]) == {} and set(h.run_tables(ids[2])) == {"p#1", "p#2"}


def test_closed_loop_refines_the_tables_that_miss_the_target(tmp_path):
    """Per-controller and per-pixel runs refine like the global run: a unit whose pixels miss
    target_de00 in a closed-loop round gets the round's points added to its fit and a new
    table, re-checked in the next round; a unit within the target keeps its table. Round 1 is
    the max_rounds = 1 run (same seeds)."""
    init_backend(config(tmp_path, ""))
    for gran in ("controller", "pixel"):
        extra = f'[tables]\ngranularity = "{gran}"\ncheck_groups = 0\n'
        one = Calibrator(config(tmp_path, extra)).run(light())
        assert one.metrics()["rounds"] == 1 and one.metrics()["refined_tables"] == 0
        devs = [u.loop_max_dev for u in one.units]
        target = float(np.median(devs))  # some units miss it, some meet it
        two = Calibrator(parse_config(BASE.replace("max_rounds = 1", f"max_rounds = 2\n"
                                                   f"target_de00 = {target}") + extra,
                                      base_dir=tmp_path)).run(light())
        m = two.metrics()
        assert m["rounds"] == 2 and [lp.round for lp in two.loop_rounds] == [1, 2]
        np.testing.assert_array_equal(two.loop_rounds[0].ogcd, one.loop.ogcd)
        assert m["refined_tables"] == sum(d > target for d in devs) > 0
        for u1, u2, dev in zip(one.units, two.units, devs, strict=True):
            same = np.array_equal(u1.lengths_um, u2.lengths_um)
            assert (u2.refined_rounds, same) == ((1, False) if dev > target else (0, True))
            np.testing.assert_array_equal(u2.characteristic.ogcd, u1.characteristic.ogcd)
        # the pushed tables are the refined ones, and the last round checked them
        stacked = np.stack([u.lengths_um for u in two.units])[two.unit_of_pixel]
        np.testing.assert_array_equal(two.loop.lengths_mm,
                                      stacked[two.loop.representatives][:, two.loop.levels]
                                      / 1000.0)
        for c, pix in zip(two_cfg_controllers(tmp_path, extra), ((0, 1), (2, 3)), strict=True):
            t = two.controller_tables[c]
            rows = stacked[list(pix)]
            np.testing.assert_array_equal(t, rows if gran == "pixel" else rows[0])
        report = two.report()
        assert [r["round"] for r in report["closed_loop_rounds"]] == [1, 2]
        assert report["closed_loop"]["round"] == 2
    # three rounds: a refit uses every round so far (each measured the unit's table of its
    # time), not only the rounds in which the unit missed: refined_rounds = its last miss
    extra = '[tables]\ngranularity = "pixel"\ncheck_groups = 0\n'
    three = Calibrator(parse_config(BASE.replace("max_rounds = 1", f"max_rounds = 3\n"
                                                 f"target_de00 = {target}") + extra,
                                    base_dir=tmp_path)).run(light())
    assert [lp.round for lp in three.loop_rounds][:2] == [1, 2]
    for i, u in enumerate(three.units):
        missed = [lp.round for lp in three.loop_rounds[:-1]
                  if lp.pixel_dev()[u.pixels].max() > target]
        assert u.refined_rounds == (max(missed) if missed else 0), (i, missed)


def two_cfg_controllers(tmp_path: Path, extra: str) -> list[str]:
    return [c.name for c in config(tmp_path, extra).controllers]


def test_closed_loop_measures_every_pixel_at_its_own_controller_table(tmp_path):
    """A pixel group can span two controllers (4 x 2 at 2 m: rows 1 and 2 are seen alike, the
    controllers own rows 0-1 and 2-3). The closed loop must check each controller's table on
    its own pixels, not one member's table for the whole group: otherwise a controller's loop
    deviation, and the points that refine its table, come from the other controller's table."""
    from grassd.daemon.core.calibration.display_model import (
        display_spec_for_config,
        group_pixels,
        pixel_geometry,
    )
    from grassd.sim.scene import Viewpoint

    text = (BASE.replace("rows = 2\ncols = 2", "rows = 4\ncols = 2")
            .replace('pixels = "0-1"', 'pixels = "0-3"').replace('pixels = "2-3"', 'pixels = "4-7"')
            + '[tables]\ngranularity = "controller"\ncheck_groups = 0\n')
    cfg = parse_config(text, base_dir=tmp_path)
    init_backend(cfg)
    res = Calibrator(cfg).run(light())
    labels = group_pixels(pixel_geometry(display_spec_for_config(cfg), Viewpoint(170, 2.0, 0.0)),
                          cfg.tables.group_tolerance_deg).labels
    spans = [g for g in np.unique(labels) if len(set(res.unit_of_pixel[labels == g])) > 1]
    assert spans, "precondition: a pixel group spans both controllers"
    lp = res.loop
    stacked = np.stack([u.lengths_um for u in res.units])[res.unit_of_pixel]
    np.testing.assert_array_equal(lp.lengths_mm[lp.labels], stacked[:, lp.levels] / 1000.0)
    np.testing.assert_array_equal(res.unit_of_pixel[lp.representatives[lp.labels]],
                                  res.unit_of_pixel)
