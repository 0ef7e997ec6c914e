"""The service in-process (real renderer, SQLite, simulated controllers on ptys, Modbus sensor):
interrupted runs, scheduled runs, reload rules, request handling."""

from __future__ import annotations

import os
from pathlib import Path

import daemon_harness
from daemon_harness import TWO_VIEWS, drop, service

from grassd.daemon.core.config.settings import load_config
from grassd.daemon.core.runtime.service import Service
from grassd.firmware_proto.client import RetryPolicy


def write_config(path: Path, state: Path, cfg, extra: str = "", interval: float = 0) -> Path:
    """daemon_harness's configuration with two viewpoints and a slower lux sensor timeout."""
    return daemon_harness.write_config(path, state, cfg, extra, interval, views=TWO_VIEWS,
                                    sensor_timeout_s=0.5)


def test_interrupted_run_is_retried_after_restart(tmp_path, hw):
    _, cfg = hw
    conf = write_config(tmp_path / "g.toml", tmp_path / "state", cfg)
    svc = service(conf)
    drop(svc.cfg.light.inbox, "b1")
    [b] = svc.inbox.poll()

    def stop_on_second_viewpoint(text: str) -> None:
        if "viewpoint 2/2" in text:
            svc.stop_event.set()

    orig = svc._progress
    svc._progress = lambda text: (orig(text), stop_on_second_viewpoint(text))
    out = svc.process_bundle(b)
    assert out.status == "interrupted"
    assert svc.history.run(out.run_id).status == "failed"
    assert svc.history.journal_get(b.hash).attempts == 0  # a clean stop does not count
    assert (svc.inbox.processing / b.id).is_dir()
    svc.shutdown()
    svc2 = service(conf)
    [again] = svc2.inbox.recover()
    assert again.hash == b.hash
    out2 = svc2.process_bundle(again)
    assert out2.status == "ok" and [c.ok for c in out2.controllers] == [True, True]
    assert svc2.history.journal_get(b.hash).state == "archived"
    assert svc2.history.run_count("ok") == 1
    svc2.shutdown()


def test_all_controllers_down_commits_then_reconciles(tmp_path, hw):
    sim, cfg = hw
    conf = write_config(tmp_path / "g.toml", tmp_path / "state", cfg)
    svc = service(conf)
    orig = svc._progress

    def unplug_before_the_push(text: str) -> None:  # ordered by the run, not by the clock
        orig(text)
        if text.startswith("pushing table"):
            for bus in sim.buses:
                bus.unplug(down_s=3.0)

    svc._progress = unplug_before_the_push
    drop(svc.cfg.light.inbox, "b")
    [b] = svc.inbox.poll()
    out = svc.process_bundle(b)
    assert out.status == "ok" and not any(c.ok for c in out.controllers)
    assert svc.history.current_table().id == out.run_id  # desired even though not pushed
    import time

    deadline = time.monotonic() + 120  # a hang guard: the buses are back after 3 s
    pushed = set()  # the two buses come back at slightly different times
    while time.monotonic() < deadline:
        reports = svc.reconcile()
        pushed |= {r.controller for r in reports if r.ok and r.pushed}
        if reports and all(r.ok for r in reports):
            break
        time.sleep(0.3)
    assert all(r.ok for r in reports) and pushed == {r.controller for r in reports}
    from grassd.daemon.core.runtime.service import collect_status

    assert collect_status(svc.history, svc.cfg).to_json()["health"] == "ok"
    svc.shutdown()


def test_scheduled_run_uses_last_bundle_and_sensor(tmp_path, hw):
    sim, cfg = hw
    conf = write_config(tmp_path / "g.toml", tmp_path / "state", cfg, interval=0.5)
    svc = service(conf)
    out = svc.scheduled_run("interval")  # no bundle yet: embedded default site + sensor lux
    assert out.status == "ok"
    r = svc.history.run(out.run_id)
    assert (r.lux, r.lux_source, r.input_hashes) == (2500.0, "modbus",
                                                     {"hdri": "embedded default_site.exr"})
    drop(svc.cfg.light.inbox, "b", lux=700.0)
    svc.tick()  # processes the bundle (manifest lux wins)
    assert svc.history.runs(1)[0].lux == 700.0
    sim.sensor.lux = 1234.5
    svc.last_run_at -= 1.0  # interval elapsed
    svc.tick()
    last = svc.history.runs(1)[0]
    assert last.trigger == "interval" and last.lux == 1234.5 and last.lux_source == "modbus"
    assert set(last.input_hashes) == {"bundle"}
    sim.sensor.silent = True
    svc.last_run_at -= 1.0
    svc.tick()  # sensor silent: the scheduled run is skipped, nothing breaks
    sim.sensor.silent = False
    assert svc.history.runs(1)[0].id == last.id
    svc.shutdown()


def test_reload_rules(tmp_path, hw):
    _, cfg = hw
    conf = write_config(tmp_path / "g.toml", tmp_path / "state", cfg)
    svc = service(conf)
    good = conf.read_text()
    conf.write_text(good.replace("samples = 64", "samples = -1"))
    assert svc.reload() is False and "simulation.samples" in svc.reload_error
    assert svc.cfg.simulation.samples == 64
    conf.write_text(good.replace("samples = 64", "samples = 36").replace(
        f'state_dir = "{tmp_path / "state"}"', f'state_dir = "{tmp_path / "elsewhere"}"'))
    assert svc.reload() is True and svc.reload_error is None
    assert svc.cfg.simulation.samples == 36
    assert svc.cfg.state_dir == tmp_path / "state"  # needs a restart: kept
    assert svc.handle_request({"cmd": "nope"})["ok"] is False
    assert svc.handle_request({"cmd": "ping"})["pid"] == os.getpid()
    svc.shutdown()



def test_reload_with_unusable_inbox_keeps_old_config(tmp_path, hw):
    """A new config that validates but cannot be set up (its inbox cannot be created) is
    refused like an invalid one: the daemon keeps running on the old config."""
    _, cfg = hw
    conf = write_config(tmp_path / "g.toml", tmp_path / "state", cfg)
    svc = service(conf)
    blocker = tmp_path / "a-file"
    blocker.write_text("not a directory")
    good = conf.read_text()
    conf.write_text(good.replace('inbox = "inbox"', f'inbox = "{blocker}/inbox"')
                    .replace("samples = 64", "samples = 36"))
    assert svc.reload() is False and svc.reload_error
    assert svc.cfg.simulation.samples == 64 and svc.cfg.light.inbox == tmp_path / "state/inbox"
    assert svc.inbox.inbox == tmp_path / "state/inbox"
    svc.tick()  # still works
    svc.shutdown()


def test_bundles_wait_for_the_schedule_but_are_settled_by_then(tmp_path, hw):
    """on_new_bundle = false: a bundle waits for the next scheduled run, and that run uses it
    (it was watched and settled meanwhile), instead of running on the old light and leaving
    the new bundle for one more interval."""
    import time

    _, cfg = hw
    conf = write_config(tmp_path / "g.toml", tmp_path / "state", cfg, interval=3600)
    conf.write_text(conf.read_text().replace("[schedule]\n", "[schedule]\non_new_bundle = false\n")
                    .replace("settle_s = 0\n", "settle_s = 0.3\n"))
    svc = service(conf)
    assert svc.cfg.schedule.on_new_bundle is False and svc.cfg.light.settle_s == 0.3
    svc.last_run_at = time.time()  # not due
    drop(svc.cfg.light.inbox, "b", lux=800.0)
    svc.tick()
    time.sleep(0.5)
    svc.tick()
    assert svc.history.run_count() == 0 and svc.inbox.counts()["inbox"] == 1  # waits
    svc.last_run_at -= 3600  # due
    svc.tick()
    [run] = svc.history.runs(5)
    assert run.trigger == "bundle" and run.lux == 800.0 and run.status == "ok"
    svc.shutdown()


def test_reload_keeps_the_state_dir_override_and_what_lies_in_it(tmp_path, hw):
    """`grassd run --state-dir X`: a reload keeps X (state_dir changes need a restart) and
    also the inbox that moved along into X, instead of switching to the file's inbox."""
    _, cfg = hw
    conf = write_config(tmp_path / "g.toml", tmp_path / "state", cfg)
    over = tmp_path / "override"
    policy = RetryPolicy(timeout_s=0.1, retries=1, restarts=1, readback_retries=2)
    svc = Service(load_config(conf).with_state_dir(over), config_path=conf, policy=policy)
    assert svc.cfg.light.inbox == over / "inbox"
    assert svc.reload() is True
    assert svc.cfg.state_dir == over
    assert svc.cfg.light.inbox == over / "inbox" and svc.inbox.inbox == over / "inbox"
    svc.shutdown()
