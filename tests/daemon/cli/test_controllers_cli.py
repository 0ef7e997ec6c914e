"""``grassd controllers`` through click's CliRunner against simulated controllers on real ptys."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys

import numpy as np
import pytest
from click.testing import CliRunner
from firmware_tiers import firmware_params

from grassd.daemon.cli.controllers import parse_addresses
from grassd.daemon.cli.main import main
from grassd.firmware_proto.client import ControllerClient, RetryPolicy
from grassd.firmware_proto.tables import table_crc
from grassd.rigs.firmware import Controller, ControllerConfig
from grassd.rigs.sim_backends import open_bus


@pytest.fixture(params=firmware_params("model", "posix", "qemu"))
def bus(request, tmp_path):
    """Controllers 1-2 (3 pixels) on one pty: the Python model or the C firmware
    (posix process, QEMU image)."""
    with open_bus(request.param, tmp_path / "state", [1, 2], n_pixels=3,
                  link_path=tmp_path / "tty0") as b:
        yield b
        assert b.errors == 0


def run(*args: str):
    return CliRunner().invoke(main, ["controllers", *args])


def test_scan_status_push(bus, tmp_path):
    r = run("scan", "--port", bus.path, "--addresses", "1-4", "--timeout", "0.02")
    assert r.exit_code == 0, r.output
    lines = r.stdout.splitlines()
    assert len(lines) == 2 and lines[0].startswith("address 1: uid 0x6a5d0001, firmware 1.0.0")
    assert "3 pixels" in lines[1]

    r = run("status", "--port", bus.path, "-a", "1,2")
    assert r.exit_code == 0 and r.stdout.splitlines() == ["address 1: no table",
                                                          "address 2: no table"]
    table = (np.arange(256) * 70).tolist()
    (tmp_path / "t.json").write_text(json.dumps({"lengths_um": table, "table_id": 77}))
    r = run("push", "--port", bus.path, "--table", str(tmp_path / "t.json"), "-a", "1-2")
    assert r.exit_code == 0, r.output
    crc = table_crc(np.array(table, dtype=np.uint16))
    assert r.stdout.splitlines()[1] == (f"address 2: table 0x0000004d crc {crc:#010x} active "
                                        f"(generation 1)")
    for c in bus.controllers:
        assert c.active_table().tolist() == table

    per_pixel = np.tile(np.arange(256) * 10, (3, 1))
    (tmp_path / "p.csv").write_text("\n".join(",".join(map(str, row)) for row in per_pixel))
    r = run("push", "--port", bus.path, "--table", str(tmp_path / "p.csv"), "-a", "2",
            "--table-id", "5")
    assert r.exit_code == 0, r.output
    r = run("status", "--port", bus.path)  # no --addresses: scans 1-32 first
    assert r.exit_code == 0, r.output
    assert r.stdout.splitlines() == [
        f"address 1: table 0x0000004d crc {crc:#010x} generation 1 bank 0 (global)",
        f"address 2: table 0x00000005 crc {table_crc(per_pixel.astype(np.uint16)):#010x} "
        f"generation 2 bank 1 (3 per-pixel)"]


def test_errors_are_one_line_with_exit_code_2(bus, tmp_path):
    r = run("scan", "--port", str(tmp_path / "absent"), "--addresses", "1")
    assert r.exit_code == 2
    assert r.stderr.startswith("grassd: error: ") and "cannot open serial port" in r.stderr
    r = run("scan", "--port", bus.path, "--addresses", "5-6", "--timeout", "0.01")
    assert r.exit_code == 2 and "no controller answered" in r.stderr
    (tmp_path / "bad.json").write_text("[1, 2, 3]")
    r = run("push", "--port", bus.path, "--table", str(tmp_path / "bad.json"), "-a", "1")
    assert r.exit_code == 2 and "bad.json" in r.stderr and "(256,)" in r.stderr
    (tmp_path / "long.csv").write_text(",".join(["30000"] * 256))
    r = run("push", "--port", bus.path, "--table", str(tmp_path / "long.csv"), "-a", "1-2")
    assert r.exit_code == 2
    assert "at most 20000 um" in r.stderr and "push failed on 2 of 2" in r.stderr
    assert all(c.active_table() is None for c in bus.controllers)
    r = run("scan", "--port", bus.path, "--rs485")
    assert r.exit_code == 2 and "RS-485 mode" in r.stderr
    r = run("status", "--port", bus.path, "-a", "0-3")
    assert r.exit_code == 2 and "addresses are 1..247" in r.output


def test_parse_addresses():
    assert parse_addresses("3, 1-2,3") == [1, 2, 3]


@pytest.mark.parametrize("firmware", firmware_params("model", "posix"))
def test_sim_command_serves_ptys_until_interrupted(tmp_path, firmware):
    """``grassd controllers sim`` in its own process: print ports, serve them, stop on Ctrl-C."""
    proc = subprocess.Popen(
        [sys.executable, "-c", "from grassd.daemon.cli.main import main; main()", "controllers",
         "sim", "--pty", "--count", "2", "--separate", "--pixels", "2",
         "--state-dir", str(tmp_path / "sim"), "--firmware", firmware],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        lines = [proc.stdout.readline() for _ in range(2)]
        paths = [line.split(" -> ")[0] for line in lines]
        assert all(os.path.islink(p) and "addresses 1, 2 pixels each" in line
                   for p, line in zip(paths, lines, strict=True)), lines
        for i, p in enumerate(paths):
            with ControllerClient(p, policy=RetryPolicy(timeout_s=0.2)) as c:
                assert c.hello(1).n_pixels == 2
                assert c.push_table(1, np.full(256, 100 * (i + 1))).table_id
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=10)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, err
    assert "simulated controllers stopped" in err
    assert not any(os.path.exists(p) for p in paths)
    # the EEPROM files persist: a new simulator on the same state dir has the tables
    r = CliRunner().invoke(main, ["controllers", "sim", "--count", "2", "--separate",
                                  "--pixels", "2", "--state-dir", str(tmp_path / "sim"),
                                  "--duration", "0.01", "--firmware", firmware])
    assert r.exit_code == 0, r.output
    eeprom = sorted((tmp_path / "sim").rglob("*.eeprom"))
    assert len(eeprom) == 2
    ctl = Controller(ControllerConfig(n_pixels=2), eeprom[1])
    assert ctl.active_table().tolist() == [200] * 256
    ctl.close()
