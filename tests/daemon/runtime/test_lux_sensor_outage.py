"""A bundle without manifest lux while the Modbus lux sensor (a real pymodbus server) is down
waits in processing/ and is retried with backoff; it runs with the sensor's lux once the sensor
is back, is rejected only after light.lux_wait_s, and a reading that is no usable illuminance
(0 lux) rejects it at once."""

from __future__ import annotations

import time

import pytest
from daemon_harness import drop, service, tick_until, write_config

from grassd.rigs.simulated_site import SimLuxSensor


def test_sensor_outage_defers_then_runs_when_back(tmp_path, hw):
    sim, cfg = hw
    conf = write_config(tmp_path / "g.toml", tmp_path / "state", cfg,
                        light_extra="lux_wait_s = 60")
    svc = service(conf, retry_s=0.3, retry_max_s=0.6)
    port = sim.sensor.port
    regmap = sim.sensor.config
    sim.sensor.stop()  # connection refused from now on
    drop(svc.cfg.light.inbox, "b", lux=None)
    svc.tick()
    assert svc.inbox.counts()["processing"] == 1 and svc.inbox.counts()["rejected"] == 0
    [w] = svc.status().to_json()["waiting_bundles"]
    assert w["bundle"] == "b" and "unreachable" in w["reason"]
    assert svc.history.run_count() == 0
    h = svc.history.journal("processing")[0]
    assert h.attempts == 0  # waiting is not a crashed attempt (max_attempts stays for those)
    time.sleep(0.35)
    svc.tick()  # second try, still down
    assert svc.inbox.counts()["processing"] == 1 and svc.history.run_count() == 0
    back = SimLuxSensor(regmap, lux=3210.0, port=port).start()
    try:
        tick_until(svc, lambda: svc.history.run_count() == 1)
        run = svc.history.runs(1)[0]
        assert (run.status, run.lux, run.lux_source) == ("ok", pytest.approx(3210.0), "modbus")
        assert svc.inbox.counts()["archive"] == 1 and svc.status().daemon.waiting_bundles == ()

        back.lux = 0.0  # a real bad value: rejected at the first try, no waiting
        drop(svc.cfg.light.inbox, "zero", lux=None)
        svc.tick()
        assert svc.inbox.counts()["rejected"] == 1 and svc.status().daemon.waiting_bundles == ()
        [rej] = list(svc.inbox.rejected.iterdir())
        assert "not a usable illuminance" in (rej / "reason.txt").read_text()
    finally:
        back.stop()
    svc.shutdown()


def test_outage_longer_than_lux_wait_rejects_with_reason(tmp_path, hw):
    sim, cfg = hw
    conf = write_config(tmp_path / "g.toml", tmp_path / "state", cfg,
                        light_extra="lux_wait_s = 1.0")
    svc = service(conf, retry_s=0.3, retry_max_s=10.0)
    sim.sensor.silent = True  # connected, but never answers: a timeout each try
    drop(svc.cfg.light.inbox, "b", lux=None)
    t0 = time.monotonic()
    svc.tick()
    assert svc.inbox.counts()["processing"] == 1
    assert "did not answer" in svc.status().to_json()["waiting_bundles"][0]["reason"]
    tick_until(svc, lambda: svc.inbox.counts()["rejected"] == 1)
    assert 1.0 <= time.monotonic() - t0 < 6.0  # bounded by lux_wait_s (+ one sensor timeout)
    [rej] = list(svc.inbox.rejected.iterdir())
    reason = (rej / "reason.txt").read_text()
    assert "stayed unavailable" in reason and "lux_wait_s = 1" in reason
    assert svc.status().to_json()["waiting_bundles"] == [] and svc.history.run_count() == 0
    sim.sensor.silent = False
    svc.shutdown()
