"""The content commands over a real control socket: a script's frame, a picture asked for by
``grassd show`` (a real process), the privilege rule, and bad requests."""

from __future__ import annotations

import os
import queue
import subprocess
import sys
import threading
import time

import numpy as np
import pytest
from content_helpers import content_config
from PIL import Image

from grassd.daemon.content.feature import ContentPlayback
from grassd.daemon.core.config.settings import default_config_text, parse_config
from grassd.daemon.core.errors import ControlError
from grassd.daemon.core.monitoring.status_types import Status
from grassd.daemon.core.runtime.control import ControlServer, request
from grassd.daemon.core.runtime.control_commands import ControlCommands
from grassd.daemon.core.store.history import History


@pytest.fixture
def daemon(tmp_path, ports, sink):
    """A control socket serving the daemon's commands with a content playback on ``sink``
    (the default site: 4 x 8 pixels); yields (config file, feature, socket path)."""
    sock = tmp_path / "control.sock"
    text = (f'state_dir = "{tmp_path / "state"}"\ncontrol_socket = "{sock}"\n'
            + default_config_text())
    cfg_file = tmp_path / "grassd.toml"
    cfg_file.write_text(text)
    cfg = parse_config(text).replace(content=content_config(ports, hold_s=0.3))
    history = History(tmp_path / "state" / "history.sqlite")
    feature = ContentPlayback(cfg, sink, history, tmp_path / "state" / "reports",
                              live=False).start()
    commands = ControlCommands(lambda: Status.__new__(Status), threading.Event(),
                               threading.Event(), queue.Queue(4), lambda name: {},
                               feature_for=lambda cmd: feature.handle
                               if feature.handles(cmd) else None)
    yield cfg_file, feature, sock, commands
    feature.stop()
    history.close()


def test_script_frame_shown_then_next_source(daemon, sink):
    _, feature, sock, commands = daemon
    srv = ControlServer(sock, commands.handle).start()
    try:
        levels = list(range(0, 256, 8))  # 32 pixels
        assert request(sock, {"cmd": "content_frame", "levels": levels, "hold_s": 0.5})["ok"]
        sink.wait_for(lambda f: f.tolist() == levels)
        st = request(sock, {"cmd": "content_status"})["content"]
        assert st["source"] == "script" and st["frames_out"] > 0
        as_hex = bytes(range(100, 132)).hex()
        assert request(sock, {"cmd": "content_frame", "levels_hex": as_hex})["ok"]
        sink.wait_for(lambda f: f.tolist() == list(range(100, 132)))
        with pytest.raises(ControlError, match="32 integers 0..255"):
            request(sock, {"cmd": "content_frame", "levels": [1, 2, 300]})
        with pytest.raises(ControlError, match="64 hex digits"):
            request(sock, {"cmd": "content_frame", "levels_hex": "zz" * 32})
        with pytest.raises(ControlError, match="hold_s"):
            request(sock, {"cmd": "content_frame", "levels": levels, "hold_s": -1})
    finally:
        srv.stop()


def test_frame_needs_privilege_status_does_not(daemon, sink):
    _, feature, sock, commands = daemon
    srv = ControlServer(sock, commands.handle, privileged_uids={os.geteuid() + 4242}).start()
    try:
        with pytest.raises(ControlError, match="permission denied"):
            request(sock, {"cmd": "content_frame", "levels": [9] * 32})
        with pytest.raises(ControlError, match="permission denied"):
            request(sock, {"cmd": "content_show", "path": "/nonexistent.png"})
        assert request(sock, {"cmd": "content_status"})["content"]["source"] == "none"
        assert sink.last() is None
    finally:
        srv.stop()


def test_grassd_show_asks_the_daemon(daemon, sink, tmp_path):
    cfg_file, feature, sock, commands = daemon
    srv = ControlServer(sock, commands.handle).start()
    gif = tmp_path / "anim.gif"
    frames = [Image.new("RGB", (80, 40), (0, g, 0)) for g in (40, 160)]
    frames[0].save(gif, save_all=True, append_images=frames[1:], duration=150, loop=0)
    try:
        proc = subprocess.run([sys.executable, "-m", "grassd.daemon.cli", "show", str(gif),
                               "--duration", "5", "--config", str(cfg_file)],
                              capture_output=True, text=True, timeout=60)
        assert proc.returncode == 0, proc.stderr
        assert "the daemon shows anim.gif (2 frame(s))" in proc.stdout
        # map "nearest_de00" without a calibration yet: luminance; both frames play
        seen = set()
        for want in (40, 160):
            lum = int(np.asarray(Image.new("RGB", (1, 1), (0, want, 0)).convert("L"))[0, 0])
            sink.wait_for(lambda f, v=lum: np.all(f == v))
            seen.add(lum)
        assert len(seen) == 2
        assert feature.status().source.value == "script"
        assert "luminance" in feature.status().map
        missing = subprocess.run([sys.executable, "-m", "grassd.daemon.cli", "show",
                                  str(tmp_path / "grassd.toml"), "--config", str(cfg_file)],
                                 capture_output=True, text=True, timeout=60)
        assert missing.returncode == 2 and "not a picture" in missing.stderr
        stop = subprocess.run([sys.executable, "-m", "grassd.daemon.cli", "show", "--stop",
                               "--config", str(cfg_file)], capture_output=True, text=True,
                              timeout=60)
        assert stop.returncode == 0, stop.stderr
        deadline = time.monotonic() + 3
        while feature.status().source.value == "script" and time.monotonic() < deadline:
            time.sleep(0.02)
        assert feature.status().source.value == "none"  # nothing below it here
        both = subprocess.run([sys.executable, "-m", "grassd.daemon.cli", "show", str(gif),
                               "--stop", "--config", str(cfg_file)], capture_output=True,
                              text=True, timeout=60)
        assert both.returncode == 2 and "not both" in both.stderr
    finally:
        srv.stop()


def test_without_content_the_daemon_says_how_to_enable_it(tmp_path):
    sock = tmp_path / "c.sock"
    commands = ControlCommands(lambda: Status.__new__(Status), threading.Event(),
                               threading.Event(), queue.Queue(4), lambda name: {})
    srv = ControlServer(sock, commands.handle).start()
    try:
        with pytest.raises(ControlError, match=r"set \[content\] enabled = true"):
            request(sock, {"cmd": "content_frame", "levels": [0]})
    finally:
        srv.stop()
