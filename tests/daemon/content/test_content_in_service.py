"""The content feature inside the service: started for an enabled [content] on the fleet's
frame output, a script's frame through the service's own request handler reaching the
simulated motors, its status in the daemon's, a measurement's hold, a reload (the content
starts again on the rebuilt fleet) and one that turns it off (the receivers' ports are free
again)."""

from __future__ import annotations

import socket
import time

import numpy as np
from daemon_harness import POLICY

from grassd.daemon.cli.features import daemon_features
from grassd.daemon.core.calibration.display_model import controller_pixels
from grassd.daemon.core.config.settings import default_config_text, load_config, load_default_config
from grassd.daemon.core.runtime.service import Service
from grassd.rigs.simulated_site import SimulatedHardware, hardware_toml


def _playback(svc):
    """The service's content playback now (None: none)."""
    return svc.features.get("content").playback


def _config(tmp_path, hw_cfg, ports, enabled: bool) -> str:
    text = default_config_text()
    head, rest = text.split("[display]", 1)
    rest = rest.split("[[viewpoints]]", 1)[1]  # the simulated ports' display and controllers
    return (f'state_dir = "{tmp_path / "state"}"\n' + head + hardware_toml(hw_cfg)
            + "\n[[viewpoints]]" + rest
            + f"\n[content]\nenabled = {str(enabled).lower()}\nhold_s = 0.5\n"
            f"[content.sacn]\nport = {ports[0]}\n[content.artnet]\nport = {ports[1]}\n")


def _targets(svc: Service) -> np.ndarray:
    cfg = svc.cfg
    n = cfg.display.pixel_count
    out = np.full(n, -1.0)
    for c, pix in zip(cfg.controllers, controller_pixels(cfg.controllers, n), strict=True):
        out[pix] = svc.fleet.client(c).read_positions(c.address)[:len(pix), 1]
    return out


def _port_free(port: int) -> bool:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        try:
            s.bind(("127.0.0.1", port))
        except OSError:
            return False
    return True


def test_service_shows_a_script_frame_and_turns_content_off_on_reload(tmp_path, ports):
    sim = SimulatedHardware(load_default_config(), tmp_path / "hw")
    hw_cfg = sim.start()
    conf = tmp_path / "grassd.toml"
    conf.write_text(_config(tmp_path, hw_cfg, ports, True))
    svc = Service(load_config(conf), features=daemon_features(), config_path=conf,
                  policy=POLICY)
    try:
        table = np.rint(np.linspace(0, 20000, 256)).astype(np.uint16)
        assert all(r.ok for r in svc.fleet.push(table, 1))
        svc.features.restart(svc, None)  # what run() does once the control socket serves
        assert _playback(svc) is not None and not _port_free(ports[0])
        n = svc.cfg.display.pixel_count
        levels = [(i * 37) % 256 for i in range(n)]
        assert svc.handle_request({"cmd": "content_frame", "levels": levels,
                                   "hold_s": 30})["ok"]
        deadline = time.monotonic() + 5
        while not np.array_equal(_targets(svc), table[levels]) and time.monotonic() < deadline:
            time.sleep(0.05)
        np.testing.assert_array_equal(_targets(svc), table[levels])
        live = svc.status().daemon.content
        assert live["source"] == "script" and live["output"]["frames_shown"] >= 1
        _playback(svc).hold()  # as a measurement does: nothing goes out while held
        assert _playback(svc).status().output["held"] is True
        _playback(svc).release()
        # a reload rebuilds the fleet: the content starts again on its new lines
        conf.write_text(_config(tmp_path, hw_cfg, ports, True).replace("hold_s = 0.5",
                                                                        "hold_s = 0.6"))
        assert svc.reload() and _playback(svc) is not None
        assert _playback(svc).cfg.content.hold_s == 0.6
        levels = [(i * 11 + 5) % 256 for i in range(n)]
        assert svc.handle_request({"cmd": "content_frame", "levels": levels,
                                   "hold_s": 30})["ok"]
        deadline = time.monotonic() + 5
        while not np.array_equal(_targets(svc), table[levels]) and time.monotonic() < deadline:
            time.sleep(0.05)
        np.testing.assert_array_equal(_targets(svc), table[levels])
        # a reload refused after the fleet was closed (an inbox that cannot be made): the
        # content starts again on the old configuration's rebuilt fleet
        blocker = tmp_path / "a-file"
        blocker.write_text("")
        conf.write_text(_config(tmp_path, hw_cfg, ports, True).replace(
            'inbox = "inbox"', f'inbox = "{blocker / "inbox"}"'))
        assert not svc.reload() and svc.reload_error and _playback(svc) is not None
        levels = [(i * 5 + 1) % 256 for i in range(n)]
        assert svc.handle_request({"cmd": "content_frame", "levels": levels,
                                   "hold_s": 30})["ok"]
        deadline = time.monotonic() + 5
        while not np.array_equal(_targets(svc), table[levels]) and time.monotonic() < deadline:
            time.sleep(0.05)
        np.testing.assert_array_equal(_targets(svc), table[levels])
        conf.write_text(_config(tmp_path, hw_cfg, ports, False))
        assert svc.reload()
        assert _playback(svc) is None and svc.status().daemon.content is None
        assert _port_free(ports[0]) and _port_free(ports[1])
    finally:
        svc.shutdown()
        sim.stop()
