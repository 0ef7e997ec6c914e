"""A bundle held back in processing/ (waiting for the Modbus lux sensor, a real pymodbus
server that is down) while a newer bundle makes the active table must not override that table
with its older light when it finally runs: it is archived as superseded (a history row with the
reason, no push). A held-back bundle whose light is newer than the active table's still runs."""

from __future__ import annotations

from datetime import datetime

from daemon_harness import drop, journal_entry, reported, service, tick_until, write_config

from grassd.rigs.simulated_site import SimLuxSensor


def test_held_back_older_bundle_is_superseded_newer_one_applies(tmp_path, hw):
    sim, cfg = hw
    conf = write_config(tmp_path / "g.toml", tmp_path / "state", cfg,
                        light_extra="lux_wait_s = 60")
    svc = service(conf, retry_s=0.3, retry_max_s=0.6)
    inbox = svc.cfg.light.inbox
    port, regmap = sim.sensor.port, sim.sensor.config
    sim.sensor.stop()  # connection refused: a bundle without manifest lux waits

    drop(inbox, "morning", lux=None, timestamp="2026-03-01T09:00:00+01:00")
    svc.tick()
    assert [w["bundle"] for w in svc.status().to_json()["waiting_bundles"]] == ["morning"]
    drop(inbox, "noon", lux=4000.0, timestamp="2026-03-01T12:00:00+01:00")
    svc.tick()  # noon has its lux: it runs and becomes the active table
    noon = svc.history.current_table()
    assert noon is not None and noon.bundle_hash == journal_entry(svc, "noon").bundle_hash
    assert noon.light_at == datetime.fromisoformat("2026-03-01T12:00:00+01:00").timestamp()
    assert reported(svc) == {(noon.table_id, noon.table_crc)}
    assert [w["bundle"] for w in svc.status().to_json()["waiting_bundles"]] == ["morning"]

    back = SimLuxSensor(regmap, lux=3210.0, port=port).start()
    try:
        tick_until(svc, lambda: journal_entry(svc, "morning").state != "processing")
        morning = journal_entry(svc, "morning")
        assert morning.state == "archived" and morning.reason.startswith("superseded: ")
        run = svc.history.run(morning.run_id)
        assert (run.status, run.bundle_hash, run.table_id) == ("superseded",
                                                               morning.bundle_hash, None)
        assert run.error == morning.reason and "older than the light" in run.error
        assert f"run {noon.id}" in run.error
        assert svc.history.pushes(run.id) == []  # nothing pushed for it
        assert (svc.inbox.archive / morning.bundle_id / "manifest.toml").exists()
        assert svc.history.current_table().id == noon.id  # noon's table stays active ...
        assert reported(svc) == {(noon.table_id, noon.table_crc)}  # ... on every controller
        # scheduled runs keep using noon's light, not the superseded bundle's
        assert svc.history.latest_archived().name == "noon"
        assert svc.status().to_json()["waiting_bundles"] == []

        # a held-back bundle whose light is NEWER than the active table's is applied
        back.stop()
        drop(inbox, "evening", lux=None, timestamp="2026-03-01T18:00:00+01:00")
        svc.tick()
        assert [w["bundle"] for w in svc.status().to_json()["waiting_bundles"]] == ["evening"]
        drop(inbox, "afternoon", lux=3000.0, timestamp="2026-03-01T15:00:00+01:00")
        svc.tick()
        afternoon = svc.history.current_table()
        assert afternoon.bundle_hash == journal_entry(svc, "afternoon").bundle_hash
        back = SimLuxSensor(regmap, lux=2000.0, port=port).start()
        tick_until(svc, lambda: journal_entry(svc, "evening").state != "processing")
        evening = svc.history.current_table()
        assert evening.id > afternoon.id and abs(evening.lux - 2000.0) < 0.5
        assert evening.bundle_hash == journal_entry(svc, "evening").bundle_hash
        assert journal_entry(svc, "evening").reason is None
        assert reported(svc) == {(evening.table_id, evening.table_crc)}
    finally:
        back.stop()
    svc.shutdown()
