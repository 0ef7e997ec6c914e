"""One grassd process per state directory: a running daemon (a real `grassd run` subprocess)
makes a one-shot `grassd calibrate --now` that cannot reach its socket, and a second daemon,
fail at once with one line naming its PID (exit 2); once it stops, the one-shot works. The same
for `grassd controllers push/scan/status` talking on the bus the daemon owns."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from daemon_harness import SITE, write_config

from grassd.daemon.core.config.settings import load_config
from grassd.daemon.core.errors import ControlError, StateDirLocked
from grassd.daemon.core.runtime.control import request
from grassd.daemon.core.runtime.service import Service
from grassd.daemon.core.runtime.statelock import StateLock

GRASSD = str(Path(sys.executable).parent / "grassd")


def wait_ping(sock: Path, proc: subprocess.Popen, timeout: float = 60) -> dict:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        assert proc.poll() is None, "daemon exited during start"
        try:
            return request(sock, {"cmd": "ping"}, timeout_s=2)
        except ControlError:
            time.sleep(0.1)
    raise AssertionError("daemon did not answer ping")


def test_daemon_excludes_one_shot_and_second_daemon(tmp_path, hw):
    _, cfg = hw
    state = tmp_path / "state"
    conf = write_config(tmp_path / "g.toml", state, cfg, lux="manifest")
    # the same state directory, but a socket nobody listens on: what a one-shot racing a
    # starting daemon (socket not yet bound) sees
    other = tmp_path / "other.toml"
    other.write_text(f'control_socket = "{tmp_path / "none.sock"}"\n' + conf.read_text())
    log = open(tmp_path / "daemon.log", "wb")
    daemon = subprocess.Popen([GRASSD, "run", "--config", str(conf), "--tick", "0.2"],
                              stdout=log, stderr=subprocess.STDOUT)
    try:
        pid = wait_ping(state / "control.sock", daemon)["pid"]
        assert pid == daemon.pid
        one = subprocess.run([GRASSD, "calibrate", "--now", "--config", str(other)],
                             capture_output=True, text=True, timeout=120)
        assert one.returncode == 2, one.stderr
        lines = one.stderr.strip().splitlines()
        assert len(lines) == 1 and f"PID {daemon.pid}" in lines[0] and str(state) in lines[0]
        assert "grassd run" in lines[0]
        two = subprocess.run([GRASSD, "run", "--config", str(other)], capture_output=True,
                             text=True, timeout=120)
        assert two.returncode == 2 and f"PID {daemon.pid}" in two.stderr
        assert len(two.stderr.strip().splitlines()) == 1, two.stderr
        assert not (tmp_path / "none.sock").exists()
        assert request(state / "control.sock", {"cmd": "ping"})["pid"] == daemon.pid  # unharmed
    finally:
        daemon.send_signal(signal.SIGTERM)
        assert daemon.wait(60) == 0
    (state / "inbox" / "b").mkdir()  # the daemon is gone: a one-shot may run now
    (state / "inbox" / "b" / "sky.exr").write_bytes(
        SITE.read_bytes())
    (state / "inbox" / "b" / "manifest.toml").write_text(
        'timestamp = 2026-03-01T12:00:00+01:00\nhdri = "sky.exr"\nambient_lux = 800.0\n')
    ok = subprocess.run([GRASSD, "calibrate", "--now", "--config", str(other)],
                        capture_output=True, text=True, timeout=300)
    assert ok.returncode == 0, ok.stderr


def test_in_process_second_service_is_refused_and_lock_released(tmp_path, hw):
    _, cfg = hw
    conf = write_config(tmp_path / "g.toml", tmp_path / "state", cfg)
    svc = Service(load_config(conf))
    with pytest.raises(StateDirLocked, match=rf"PID {os.getpid()}\)"):
        Service(load_config(conf))
    svc.shutdown()
    Service(load_config(conf)).shutdown()  # released at shutdown


def test_controllers_commands_refuse_a_bus_a_running_daemon_owns(tmp_path, hw):
    """`grassd controllers push/scan/status` against a real `grassd run --simulate-hardware`
    on the same configuration: one line naming the daemon's PID and what to do instead
    (exit 2), nothing sent on its bus; a port the daemon does not own is usable meanwhile;
    once the daemon stopped, the push goes through."""
    sim, cfg = hw
    state = tmp_path / "state"
    conf = write_config(tmp_path / "g.toml", state, cfg, lux="manifest")
    table = tmp_path / "t.json"
    table.write_text(json.dumps({"lengths_um": [i * 70 for i in range(256)], "table_id": 4242}))
    log = open(tmp_path / "daemon.log", "wb")
    daemon = subprocess.Popen([GRASSD, "run", "--simulate-hardware", "--config", str(conf),
                               "--tick", "0.2"], stdout=log, stderr=subprocess.STDOUT)
    try:
        wait_ping(state / "control.sock", daemon)
        ports = re.findall(r"simulated controller port \S+ -> (\S+)",
                           (tmp_path / "daemon.log").read_text())
        assert ports, (tmp_path / "daemon.log").read_text()
        cmds = {"push": ["push", "--table", str(table), "-a", "1"],
                "scan": ["scan", "-a", "1"], "status": ["status", "-a", "1"]}
        for name, args in cmds.items():
            r = subprocess.run([GRASSD, "controllers", *args, "--port", ports[0],
                                "--config", str(conf)], capture_output=True, text=True,
                               timeout=60)
            assert r.returncode == 2, (name, r.stdout, r.stderr)
            lines = r.stderr.strip().splitlines()
            assert len(lines) == 1 and f"PID {daemon.pid}" in lines[0], r.stderr
            assert str(state) in lines[0] and f"grassd controllers {name}" in lines[0]
            want = "grassd calibrate --now" if name == "push" else "grassd status"
            assert want in lines[0] and "stop the daemon" in lines[0]
            assert r.stdout == ""
        assert request(state / "control.sock", {"cmd": "ping"})["pid"] == daemon.pid
        # another port (the fixture's bus: a spare controller on a bench adapter) stays usable
        spare = cfg.controllers[0]
        r = subprocess.run([GRASSD, "controllers", "status", "-a", str(spare.address),
                            "--port", spare.port, "--config", str(conf)],
                           capture_output=True, text=True, timeout=60)
        assert r.returncode == 0 and str(spare.address) in r.stdout, r.stderr
        assert request(state / "control.sock", {"cmd": "ping"})["pid"] == daemon.pid
    finally:
        daemon.send_signal(signal.SIGTERM)
        assert daemon.wait(60) == 0
    dev = sim.buses[0].controllers[0]
    r = subprocess.run([GRASSD, "controllers", "push", "--table", str(table), "-a",
                        str(cfg.controllers[0].address), "--port", cfg.controllers[0].port,
                        "--config", str(conf)], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr  # the daemon is gone: the bus is free
    assert list(dev.active_table()) == [i * 70 for i in range(256)]


def test_controllers_help_says_a_running_daemon_owns_the_bus():
    for cmd in ("push", "scan", "status"):
        r = subprocess.run([GRASSD, "controllers", cmd, "--help"], capture_output=True,
                           text=True, timeout=60)
        assert r.returncode == 0 and "running daemon" in " ".join(r.stdout.split()), r.stdout


def test_shared_check_creates_nothing_and_keeps_a_daemon_out_while_held(tmp_path):
    state = tmp_path / "state"
    with StateLock(state).shared(lambda who: who):  # no grassd ever ran here
        pass
    assert not state.exists()
    StateLock(state).acquire().release()  # a daemon ran and stopped: the file stays
    with StateLock(state).shared(lambda who: who):
        with pytest.raises(StateDirLocked):
            StateLock(state).acquire()  # a daemon starting meanwhile is refused
    StateLock(state).acquire().release()


def test_shared_check_lets_other_ports_through_only_when_the_holder_lists_its_own(tmp_path):
    """A holder that listed its serial ports (symlinks resolved) refuses only those; one that
    listed none (an older grassd) refuses every port."""
    state = tmp_path / "state"
    bus = tmp_path / "ttyBUS0"
    bus.touch()
    (tmp_path / "link0").symlink_to(bus)
    held = StateLock(state, "grassd run").acquire()
    try:
        for port in (str(bus), str(tmp_path / "other")):
            with pytest.raises(StateDirLocked, match="grassd run"):
                with StateLock(state).shared(lambda who: who, port=port):
                    pass
        held.note_ports([str(tmp_path / "link0")])
        assert StateLock(state).holder_ports() == {str(bus)}
        assert StateLock(state).holder() == (os.getpid(), "grassd run")
        with StateLock(state).shared(lambda who: who, port=str(tmp_path / "other")):
            pass
        for port in (str(bus), str(tmp_path / "link0")):
            with pytest.raises(StateDirLocked):
                with StateLock(state).shared(lambda who: who, port=port):
                    pass
        with pytest.raises(StateDirLocked):
            with StateLock(state).shared(lambda who: who):  # no port named
                pass
    finally:
        held.release()


def test_a_running_daemon_lists_its_rtu_lux_sensor_port_too(tmp_path, hw):
    """An RS-485 (Modbus RTU) lux sensor's port is the daemon's as much as the controllers'
    buses: `grassd controllers` must be refused there too (a second master on that bus)."""
    import dataclasses

    _, cfg = hw
    conf = load_config(write_config(tmp_path / "g.toml", tmp_path / "state", cfg))
    sensor_port = tmp_path / "rs485-lux"
    modbus = dataclasses.replace(conf.light.modbus, mode="rtu", serial_port=str(sensor_port))
    conf = conf.replace(light=dataclasses.replace(conf.light, modbus=modbus))
    svc = Service(conf)
    try:
        owned = StateLock(conf.state_dir).holder_ports()
        assert owned == {os.path.realpath(c.port) for c in conf.controllers} | {str(sensor_port)}
    finally:
        svc.shutdown()
