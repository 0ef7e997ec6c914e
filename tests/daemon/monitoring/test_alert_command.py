"""The alert command on health changes: a real script run by the daemon (real renderer, SQLite,
simulated controllers on ptys) when a controller goes silent and when it comes back; the rate
limit, a failing command and a command that does not return, with the Alerter alone."""

from __future__ import annotations

import json
import logging
import sys
from pathlib import Path

from daemon_harness import drop, service, tick_until, write_config

from grassd.daemon.core.config.settings import AlertsConfig
from grassd.daemon.core.monitoring.alerts import META_KEY, Alerter
from grassd.daemon.core.monitoring.health import Health
from grassd.daemon.core.store.history import History

#: the alert command: appends one JSON line per alert (its stdin plus its environment) to the
#: file named by its first argument; with a second argument it first waits until that file
#: exists (so a test can hold it running)
SCRIPT = f"""#!{sys.executable}
import json, os, sys, time
event = json.load(sys.stdin)
if len(sys.argv) > 2:
    while not os.path.exists(sys.argv[2]):
        time.sleep(0.02)
event["env"] = [os.environ["GRASSD_PREVIOUS_HEALTH"], os.environ["GRASSD_HEALTH"]]
with open(sys.argv[1], "a") as fh:
    fh.write(json.dumps(event) + "\\n")
"""


def alert_script(tmp_path: Path) -> Path:
    path = tmp_path / "alert.py"
    path.write_text(SCRIPT)
    path.chmod(0o755)
    return path


def alerts(out: Path) -> list[dict]:
    return [json.loads(line) for line in out.read_text().splitlines()] if out.exists() else []


def test_silent_controller_alerts_once_and_once_on_recovery(tmp_path, hw):
    sim, cfg = hw
    out = tmp_path / "alerts.jsonl"
    conf = write_config(tmp_path / "g.toml", tmp_path / "state", cfg,
                        extra=f'[alerts]\ncommand = "{alert_script(tmp_path)} {out}"\n'
                              "min_interval_s = 0\n")
    svc = service(conf)
    drop(svc.cfg.light.inbox, "b1")
    svc.tick()  # the first table reaches both controllers: ok (taken as known, no alert)
    svc.operator.alerter.wait(10)
    assert svc.operator.health.level == "ok" and alerts(out) == []
    bus = sim.buses[0]
    bus.unplug(down_s=4.0)  # the pty closes: the controller answers nothing

    def alerted(n: int):
        svc.operator.alerter.wait(10)
        return len(alerts(out)) >= n

    tick_until(svc, lambda: alerted(1))
    [gone] = alerts(out)
    assert (gone["previous"], gone["level"], gone["env"]) == ("ok", "degraded",
                                                             ["ok", "degraded"])
    assert any(bus.path in r and "unreachable" in r for r in gone["reasons"]), gone
    assert gone["service"] == "grassd" and gone["health"].startswith("degraded")
    assert [(c["name"].startswith(bus.path), c["reachable"]) for c in gone["controllers"]] == [
        (True, False), (False, True)]
    tick_until(svc, lambda: alerted(2))  # it comes back and gets its table again
    back = alerts(out)[1]
    assert (back["previous"], back["level"], back["reasons"]) == ("degraded", "ok", [])
    for _ in range(20):  # no further alert while nothing changes
        svc.tick()
    svc.operator.alerter.wait(10)
    assert len(alerts(out)) == 2
    assert svc.history.get_meta(META_KEY) == "ok"
    svc.shutdown()


DOWN = Health("degraded", ("controller x unreachable",))
FAILED = Health("failed", ("no controller holds table 1",))
OK = Health("ok")


def test_rate_limit_sums_up_changes(tmp_path):
    out = tmp_path / "alerts.jsonl"
    with History(tmp_path / "state.db") as h:
        a = Alerter(AlertsConfig(command=f"{alert_script(tmp_path)} {out}", min_interval_s=60),
                    h)
        assert a.observe(OK, now=0) is False  # first level: known
        assert a.observe(DOWN, now=1) is True
        a.wait(10)
        assert a.observe(FAILED, now=2) is False  # within the interval: held
        assert a.observe(FAILED, now=30) is False
        assert a.observe(FAILED, now=62) is True  # then one alert for what happened
        a.wait(10)
        assert a.observe(OK, now=70) is False  # held ...
        assert a.observe(FAILED, now=80) is False  # ... and back: nothing to say
        assert a.observe(FAILED, now=200) is False
        a.wait(10)
    first, second = alerts(out)
    assert (first["previous"], first["level"]) == ("ok", "degraded")
    assert (second["previous"], second["level"]) == ("degraded", "failed")
    assert [(c["from"], c["to"]) for c in second["changes"]] == [("degraded", "failed")]
    assert second["reasons"] == list(FAILED.reasons)


def test_level_alerted_survives_a_restart(tmp_path):
    out = tmp_path / "alerts.jsonl"
    cfg = AlertsConfig(command=f"{alert_script(tmp_path)} {out}", min_interval_s=0)
    with History(tmp_path / "state.db") as h:
        a = Alerter(cfg, h)
        a.observe(OK, now=0)
        assert a.observe(DOWN, now=1) is True
        a.wait(10)
    with History(tmp_path / "state.db") as h:  # a new daemon: still degraded, no repeat
        a = Alerter(cfg, h)
        assert a.observe(DOWN, now=0) is False
        assert a.observe(OK, now=1) is True
        a.wait(10)
    with History(tmp_path / "other.db") as h:  # a new state directory starting failed alerts
        a = Alerter(cfg, h)
        assert a.observe(FAILED, now=0) is True
        a.wait(10)
    assert [(e["previous"], e["level"]) for e in alerts(out)] == [
        ("ok", "degraded"), ("degraded", "ok"), ("ok", "failed")]


def test_observe_does_not_wait_for_the_command(tmp_path):
    out, release = tmp_path / "alerts.jsonl", tmp_path / "release"
    with History(tmp_path / "state.db") as h:
        a = Alerter(AlertsConfig(command=f"{alert_script(tmp_path)} {out} {release}",
                                 min_interval_s=0), h)
        a.observe(OK, now=0)
        assert a.observe(DOWN, now=1) is True  # returned while the command waits
        assert alerts(out) == []
        assert a.observe(OK, now=2) is False  # one command at a time: this change waits
        release.touch()
        a.wait(10)
        assert a.observe(OK, now=3) is True
        a.wait(10)
    assert [(e["previous"], e["level"]) for e in alerts(out)] == [("ok", "degraded"),
                                                                  ("degraded", "ok")]


def test_without_a_command_levels_are_only_followed(tmp_path):
    out = tmp_path / "alerts.jsonl"
    with History(tmp_path / "state.db") as h:
        a = Alerter(AlertsConfig(command=None), h)
        for i, health in enumerate((OK, DOWN, FAILED, DOWN) * 30):
            assert a.observe(health, now=i) is False
        a.configure(AlertsConfig(command=f"{alert_script(tmp_path)} {out}", min_interval_s=0))
        assert a.observe(DOWN, now=200) is False  # the level then current is known
        assert a.observe(OK, now=201) is True
        a.wait(10)
    [event] = alerts(out)
    assert (event["previous"], event["level"], len(event["changes"])) == ("degraded", "ok", 1)


def test_failing_command_is_logged_not_fatal(tmp_path, caplog):
    caplog.set_level(logging.ERROR, "grassd.daemon.core.monitoring.alerts")
    fails = tmp_path / "fails.sh"
    fails.write_text("#!/bin/sh\necho 'no route to ops' >&2\nexit 3\n")
    fails.chmod(0o755)
    hangs = tmp_path / "hangs.sh"
    hangs.write_text("#!/bin/sh\nexec sleep 30\n")
    hangs.chmod(0o755)
    for i, (cmd, timeout) in enumerate(((str(fails), 60.0), (str(tmp_path / "missing"), 60.0),
                                        (str(hangs), 0.3))):
        with History(tmp_path / f"state{i}.db") as h:
            a = Alerter(AlertsConfig(command=cmd, min_interval_s=0, timeout_s=timeout), h)
            a.observe(OK, now=0)
            assert a.observe(DOWN, now=1) is True
            a.wait(10)
            [(argv, code, _)] = a.runs
            assert argv == [cmd] and code in (3, None)
            assert a.observe(DOWN, now=2) is False  # not retried: the next change alerts
    text = caplog.text
    assert "failed with exit status 3" in text and "no route to ops" in text
    assert "cannot run" in text and "missing" in text
    assert "killed after 0.3 s" in text
