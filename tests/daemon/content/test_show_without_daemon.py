"""``grassd show FILE`` when no daemon runs: a real process plays the picture on the
configured (simulated) controllers itself, then closes them."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
from PIL import Image

from grassd.daemon.core.calibration.display_model import controller_pixels
from grassd.daemon.core.config.settings import default_config_text, load_default_config
from grassd.daemon.core.hardware.fleet import Fleet
from grassd.rigs.simulated_site import SimulatedHardware, hardware_toml


def test_show_plays_here_when_no_daemon_runs(tmp_path):
    sim = SimulatedHardware(load_default_config(), tmp_path / "hw")
    cfg = sim.start()
    try:
        table = np.rint(np.linspace(0, 20000, 256)).astype(np.uint16)
        fleet = Fleet(cfg.controllers)
        assert all(r.ok for r in fleet.push(table, 1))
        fleet.close()
        head, rest = default_config_text().split("[display]", 1)
        conf = tmp_path / "grassd.toml"
        conf.write_text(f'state_dir = "{tmp_path / "state"}"\ncontrol_socket = '
                        f'"{tmp_path / "nobody.sock"}"\n' + head + hardware_toml(cfg)
                        + "\n[[viewpoints]]" + rest.split("[[viewpoints]]", 1)[1]
                        + '\n[content]\nmap = "green"\n')
        rows, cols = cfg.display.rows, cfg.display.cols
        pic = np.zeros((rows * 10, cols * 10, 3), np.uint8)
        pic[..., 1] = (np.arange(cols * 10) * 3 % 256)[None, :]  # green ramps left to right
        Image.fromarray(pic).save(tmp_path / "ramp.png")
        proc = subprocess.run([sys.executable, "-m", "grassd.daemon.cli", "show",
                               str(tmp_path / "ramp.png"), "--duration", "1.5", "--config",
                               str(conf)], capture_output=True, text=True, timeout=60)
        assert proc.returncode == 0, proc.stderr
        assert "here for 1.5 s (no daemon runs)" in proc.stdout and "shown" in proc.stdout
        want = np.asarray(Image.fromarray(pic).resize((cols, rows), Image.Resampling.BOX))
        levels = want[..., 1].ravel()
        fleet = Fleet(cfg.controllers)
        n = cfg.display.pixel_count
        got = np.full(n, -1.0)
        for c, pix in zip(cfg.controllers, controller_pixels(cfg.controllers, n), strict=True):
            got[pix] = fleet.client(c).read_positions(c.address)[:len(pix), 1]
        fleet.close()
        np.testing.assert_array_equal(got, table[levels])
    finally:
        sim.stop()


def test_show_here_says_when_no_controller_took_a_frame(tmp_path):
    """Ports that do not exist: the picture plays to nobody, and the command says so."""
    conf = tmp_path / "grassd.toml"
    conf.write_text(f'state_dir = "{tmp_path / "state"}"\ncontrol_socket = '
                    f'"{tmp_path / "nobody.sock"}"\n'
                    + default_config_text().replace("/dev/serial/by-id/",
                                                    str(tmp_path / "none-")))
    Image.new("RGB", (8, 4), (0, 99, 0)).save(tmp_path / "p.png")
    proc = subprocess.run([sys.executable, "-m", "grassd.daemon.cli", "show",
                           str(tmp_path / "p.png"), "--duration", "0.5", "--config", str(conf)],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2, proc.stdout + proc.stderr
    assert "no controller took a frame of p.png" in proc.stderr
