"""Prometheus metrics in node_exporter's textfile: written by the daemon (real renderer, SQLite,
simulated controllers on ptys, pymodbus lux sensor) after runs and reconciles, and read back
with prometheus_client's own parser."""

from __future__ import annotations

import json
import re
import time
from pathlib import Path

from daemon_harness import drop, service, write_config
from prometheus_client.parser import text_string_to_metric_families

from grassd.daemon.core.config.settings import parse_config
from grassd.daemon.core.monitoring.metrics import TEXTFILE_NAME, state_dir_textfile, textfile_path

RULES = Path(__file__).resolve().parents[3] / "systemd" / "grassd-alerts.rules.yml"


def scrape(path: Path) -> dict[tuple[str, tuple], float]:
    """(sample name, sorted labels) -> value of every sample in the textfile at ``path``."""
    out = {}
    for fam in text_string_to_metric_families(path.read_text()):
        for s in fam.samples:
            out[(s.name, tuple(sorted(s.labels.items())))] = s.value
    return out


def one(samples: dict, name: str, **labels: str) -> float:
    return samples[(name, tuple(sorted(labels.items())))]


def test_textfile_default_and_configured_path(tmp_path):
    state = tmp_path / "state"
    debian = tmp_path / "node-exporter"
    assert textfile_path(None, state, debian) == state / "metrics" / TEXTFILE_NAME
    debian.mkdir()
    assert textfile_path(None, state, debian) == debian / TEXTFILE_NAME
    assert textfile_path(tmp_path / "x.prom", state, debian) == tmp_path / "x.prom"
    assert state_dir_textfile(state) == state / "metrics" / TEXTFILE_NAME


def test_textfile_must_end_in_prom(tmp_path):
    import pytest

    from grassd.daemon.core.config.settings import load_default_config
    from grassd.daemon.core.errors import ConfigError
    from grassd.rigs.simulated_site import hardware_toml

    base = (f'state_dir = "{tmp_path}"\n[site]\nlatitude = 1\nlongitude = 1\n'
            f"{hardware_toml(load_default_config())}[[viewpoints]]\nh_cm = 170\nd_m = 2\n"
            '[light]\ninbox = "in"\n')
    cfg = parse_config(base + '[metrics]\ntextfile = "m/grassd.prom"\n', base_dir=tmp_path)
    assert cfg.metrics.textfile == tmp_path / "m/grassd.prom"
    with pytest.raises(ConfigError, match=r"metrics\.textfile.*\.prom"):
        parse_config(base + '[metrics]\ntextfile = "grassd.txt"\n', base_dir=tmp_path)


def test_every_metric_after_simulated_hardware_runs(tmp_path, hw):
    sim, cfg = hw
    prom = tmp_path / "node-exporter" / "grassd.prom"
    conf = write_config(tmp_path / "g.toml", tmp_path / "state", cfg,
                        extra=f'[metrics]\ntextfile = "{prom}"\n')
    svc = service(conf)
    assert svc.operator.textfile == prom
    t0 = time.time()

    # one applied bundle (manifest lux), then one whose light is older: superseded
    drop(svc.cfg.light.inbox, "b1", lux=1000.0, timestamp="2026-03-01T12:00:00+01:00")
    svc.tick()
    drop(svc.cfg.light.inbox, "old", lux=900.0, timestamp="2026-02-01T12:00:00+01:00")
    svc.tick()
    # a bad bundle: rejected with its reason
    bad = svc.cfg.light.inbox / ".bad"
    bad.mkdir()
    (bad / "sky.exr").write_bytes(b"not an EXR file")
    (bad / "manifest.toml").write_text('timestamp = 2026-03-01T12:00:00Z\nhdri = "sky.exr"\n')
    bad.rename(svc.cfg.light.inbox / "bad")
    svc.tick()
    # a bundle attempted max_attempts times without finishing (a crash each time): quarantined
    drop(svc.cfg.light.inbox, "poison", lux=800.0, timestamp="2026-03-02T12:00:00+01:00")
    [poison] = svc.inbox.poll()
    for _ in range(svc.inbox.max_attempts):
        svc.inbox.begin(poison)
    assert svc.inbox.recover() == []
    # a scheduled run: lux from the Modbus sensor (2500 lux)
    out = svc.scheduled_run("interval")
    assert out.status == "ok"
    # one bundle waiting in the inbox (not polled)
    drop(svc.cfg.light.inbox, "waiting", lux=700.0)
    svc.reconcile()

    m = scrape(prom)
    cur = svc.history.current_table()
    report = json.loads(Path(cur.report_path).read_text())["metrics"]
    assert cur.id == out.run_id
    assert one(m, "grassd_up") == 1
    assert one(m, "grassd_health") == 0
    assert one(m, "grassd_last_success_timestamp_seconds") == cur.finished_at
    assert t0 < cur.finished_at <= time.time()
    assert one(m, "grassd_last_success_duration_seconds") == cur.finished_at - cur.started_at
    assert 0 < cur.finished_at - cur.started_at < 600
    assert one(m, "grassd_table_id") == cur.table_id
    assert one(m, "grassd_table_ogcd_range_de00") == report["ogcd_range_de00"] > 0
    assert one(m, "grassd_table_r2") == report["r2_closed_loop"]
    assert one(m, "grassd_table_max_deviation_de00") == report["max_dev_de00"]
    assert one(m, "grassd_lux", source="modbus") == 2500.0
    assert one(m, "grassd_lux_sensor_up") == 1
    assert t0 < one(m, "grassd_lux_sensor_last_success_timestamp_seconds") <= time.time()
    for outcome, n in (("applied", 1), ("superseded", 1), ("rejected", 1), ("quarantined", 1)):
        assert one(m, "grassd_bundles", outcome=outcome) == n, outcome
    assert one(m, "grassd_bundle_queue", queue="inbox") == 1
    assert one(m, "grassd_bundle_queue", queue="processing") == 0
    states = {c.name: c for c in svc.history.controllers()}
    assert len(states) == 2
    for name, st in states.items():
        assert one(m, "grassd_controller_reachable", controller=name) == 1
        assert one(m, "grassd_controller_in_sync", controller=name) == 1
        assert one(m, "grassd_controller_push_failures_total", controller=name) == 0
        assert one(m, "grassd_controller_last_seen_timestamp_seconds",
                   controller=name) == st.last_seen
    assert not any(k[0].startswith("grassd_capture") for k in m)  # no capture station yet
    lines = svc.status().daemon.lines
    assert len(lines) == 2  # the two simulated buses, clean: every request answered
    for port, q in lines.items():
        assert one(m, "grassd_line_recent_unanswered_ratio", port=port) == 0.0
        assert one(m, "grassd_line_chunk_bytes", port=port) == q["chunk_bytes"] > 0
        assert one(m, "grassd_line_request_tries_total", port=port) == q["tries"] > 0
        assert one(m, "grassd_line_request_unanswered_total", port=port) == 0

    # the lux sensor goes silent: a scheduled run is skipped, the metric says so
    sim.sensor.silent = True
    assert svc.scheduled_run("interval").status == "skipped"
    sim.sensor.silent = False
    svc.reconcile()
    m = scrape(prom)
    assert one(m, "grassd_lux_sensor_up") == 0
    assert one(m, "grassd_lux", source="modbus") == 2500.0  # the last reading stays

    # a controller goes away: unreachable, out of sync, one failed push; the other is fine
    down = sim.buses[0]
    name0 = next(n for n in states if n.startswith(down.path))
    name1 = next(n for n in states if n != name0)
    down.unplug(down_s=2.0)
    svc.reconcile()
    m = scrape(prom)
    assert one(m, "grassd_health") == 1
    assert one(m, "grassd_controller_reachable", controller=name0) == 0
    assert one(m, "grassd_controller_in_sync", controller=name0) == 0
    assert one(m, "grassd_controller_push_failures_total", controller=name0) == 1
    assert one(m, "grassd_controller_push_failures_total", controller=name1) == 0
    assert one(m, "grassd_controller_in_sync", controller=name1) == 1

    # no capture station: no capture metric (test_capture_daemon_loop checks it with one)
    assert "grassd_capture_last_success_timestamp_seconds" not in {k[0] for k in scrape(prom)}
    assert not list(prom.parent.glob(".*"))  # no temporary file left beside it
    svc.shutdown()
    assert one(scrape(prom), "grassd_up") == 0  # a clean stop says so

    # the example alert rules use only metrics the daemon writes
    import yaml

    rules = yaml.safe_load(RULES.read_text())["groups"][0]["rules"]
    written = {fam.name for fam in text_string_to_metric_families(prom.read_text())}
    written |= {k[0] for k in scrape(prom)}
    used = {n for r in rules for n in re.findall(r"grassd_[a-z0-9_]+", r["expr"])}
    assert {"grassd_last_success_timestamp_seconds", "grassd_controller_in_sync",
            "grassd_table_r2", "grassd_lux_sensor_up"} <= used
    assert used <= written, used - written


def test_unwritable_textfile_is_logged_once_never_fatal(tmp_path, hw, caplog):
    import logging

    _, cfg = hw
    blocker = tmp_path / "not-a-dir"
    blocker.write_text("a file where the directory should be")
    conf = write_config(tmp_path / "g.toml", tmp_path / "state", cfg,
                        extra=f'[metrics]\ntextfile = "{blocker}/grassd.prom"\n')
    svc = service(conf)
    caplog.set_level(logging.WARNING, "grassd.daemon.core.monitoring.operator_view")
    drop(svc.cfg.light.inbox, "b1")
    svc.tick()
    for _ in range(3):
        svc.reconcile()
    assert svc.history.current_table() is not None  # the run went through
    msgs = [r.getMessage() for r in caplog.records if "cannot write the metrics" in r.getMessage()]
    assert len(msgs) == 1 and str(blocker) in msgs[0] and "[metrics] textfile" in msgs[0]
    assert (svc.reports_dir / "index.html").is_file()  # the page does not depend on it
    svc.shutdown()
