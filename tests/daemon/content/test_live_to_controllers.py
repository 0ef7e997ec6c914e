"""Real senders (the ``sacn`` library's and stupidArtnet) through the receiver, the player and
the frame output to simulated controllers (the Python model and the C posix firmware on
ptys): every motor's target, as the controllers report it (GET_POSITIONS), is
``table[level]`` of the frame sent, on every controller of both buses."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest
from content_helpers import CapturingSink, content_config
from firmware_tiers import firmware_params
from stupidArtnet import StupidArtnet

from grassd.daemon.content.frames import FrameOutput
from grassd.daemon.content.player import ContentPlayer
from grassd.daemon.content.status import ContentSource
from grassd.daemon.core.calibration.display_model import controller_pixels
from grassd.daemon.core.config.settings import load_default_config
from grassd.daemon.core.hardware.fleet import Fleet
from grassd.rigs.simulated_site import SimulatedHardware


class _Tee:
    """Offers to the frame output and keeps a copy (to know what was sent)."""

    def __init__(self, out: FrameOutput) -> None:
        self.out, self.kept = out, CapturingSink()

    def offer(self, levels):
        self.kept.offer(levels)
        self.out.offer(levels)

    def hold(self):
        self.out.hold()

    def release(self):
        self.out.release()


def _targets(fleet: Fleet, cfg) -> np.ndarray:
    """(n_pixels,) every display pixel's motor target [um] as its controller reports it."""
    n = cfg.display.pixel_count
    out = np.full(n, -1.0)
    for c, pix in zip(cfg.controllers, controller_pixels(cfg.controllers, n), strict=True):
        out[pix] = fleet.client(c).read_positions(c.address)[:len(pix), 1]
    return out


class ArtnetSender:
    """stupidArtnet sending the latest levels to 127.0.0.1:``port`` (Art-Net universe 0)
    ``fps`` times a second from a thread of its own, as a lighting desk keeps sending."""

    def __init__(self, port: int, n: int, fps: float = 40.0) -> None:
        self.art = StupidArtnet("127.0.0.1", 0, n, fps, port=port)
        self.period = 1.0 / fps
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def send(self, levels: np.ndarray) -> None:
        """From now on send ``levels`` (n,) uint8."""
        with self._lock:
            self.art.set(bytearray(levels.tobytes()))

    def _run(self) -> None:
        while not self._stop.wait(self.period):
            with self._lock:
                self.art.show()

    def close(self) -> None:
        self._stop.set()
        self._thread.join(5)
        self.art.close()


@pytest.mark.parametrize("firmware", firmware_params("model", "posix"))
@pytest.mark.parametrize("protocol", ["sacn", "artnet"])
def test_live_frame_reaches_every_motor_as_table_of_level(tmp_path, ports, sacn_senders,
                                                           protocol, firmware):
    base = load_default_config()
    sim = SimulatedHardware(base, tmp_path / "hw", firmware=firmware)
    cfg = sim.start()
    fleet = Fleet(cfg.controllers)
    table = np.rint(np.linspace(0, 20000, 256)).astype(np.uint16)
    out = None
    try:
        reports = fleet.push(table, 7)
        assert all(r.ok for r in reports), reports
        out = FrameOutput(cfg.controllers, cfg.display.pixel_count, fps=30.0, fleet=fleet)
        tee = _Tee(out)
        only = {"artnet_enabled": False} if protocol == "sacn" else {"sacn_enabled": False}
        player = ContentPlayer(content_config(ports, hold_s=5.0, **only),
                               cfg.display.rows, cfg.display.cols, tee).start()
        n = cfg.display.pixel_count
        art = ArtnetSender(ports[1], n) if protocol == "artnet" else None
        try:
            snd = sacn_senders(ports[0]) if protocol == "sacn" else None
            for step in range(3):
                stream = ((np.arange(n) * 13 + step * 71) % 256).astype(np.uint8)
                if snd is not None:
                    snd[1].dmx_data = tuple(int(v) for v in stream)
                else:
                    art.send(stream)
                tee.kept.wait_for(lambda f, s=stream: np.array_equal(f, s))
                deadline = time.monotonic() + 5
                while time.monotonic() < deadline:
                    got = _targets(fleet, cfg)
                    if np.array_equal(got, table[stream].astype(float)):
                        break
                    time.sleep(0.02)
                np.testing.assert_array_equal(got, table[stream].astype(float))
            st = out.stats()
            assert st.frames_shown >= 3 and st.latency_ms_median is not None
            rx = player.receivers[ContentSource(protocol)].stats
            assert rx.accepted >= 3 and rx.malformed == rx.oversized == 0, rx
        finally:
            if art is not None:
                art.close()
            player.stop()
    finally:
        if out is not None:
            out.close()
        fleet.close()
        sim.stop()
