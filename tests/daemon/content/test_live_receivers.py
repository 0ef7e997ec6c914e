"""Real senders on 127.0.0.1 through the receivers and the player to a frame sink: the sACN
library's sender and stupidArtnet; pixel orders, several universes, priorities, HTP, a
terminated stream, silence and hold. The frames go to a capturing sink (the player's output,
no controllers); through a source's silence they keep at least 90 % of ``fps`` and the peak
RSS grows at most 16 MiB."""

from __future__ import annotations

import time

import numpy as np
import pytest
from content_helpers import RATE_KEPT, RSS_GROWTH_MIB, CapturingSink, content_config
from stupidArtnet import StupidArtnet

from grassd.daemon.content.pixel_order import stream_to_display
from grassd.daemon.content.player import ContentPlayer
from grassd.daemon.content.status import ContentSource
from grassd.rigs.peak_memory import peak_rss_growth

ROWS, COLS = 4, 8


FPS = 30  # [content] fps's default
#: how long the next source's frames are counted after it took over [s]
AFTER_S = 0.5


def _player(cfg, sink, rows=ROWS, cols=COLS):
    return ContentPlayer(cfg, rows, cols, sink).start()


def _through_silence(sink: CapturingSink, t_silent: float, taken_over
                     ) -> tuple[float, float, int]:
    """From a live source's silence at monotonic ``t_silent`` until ``AFTER_S`` after the
    first frame for which ``taken_over`` holds: (seconds until that frame, frames per second
    the sink was offered over the whole time, peak RSS growth [bytes])."""
    took = []

    def silence() -> None:
        sink.wait_for(taken_over, timeout_s=3.0)
        took.append(time.monotonic() - t_silent)
        time.sleep(AFTER_S)

    raised, _, growth = peak_rss_growth(silence, every_s=0.01)
    if raised is not None:
        raise raised
    rate = sink.rate(t_silent, time.monotonic())
    print(f"silence: next source after {took[0]:.2f} s; frames {rate:.1f}/s through it; "
          f"peak RSS +{growth / 2**20:.1f} MiB")
    return took[0], rate, growth


@pytest.mark.parametrize("order,serpentine,first", [
    ("rows", False, "top-left"), ("columns", True, "bottom-right"),
    ("rows", True, "top-right")])
def test_sacn_frame_lands_in_pixel_order(ports, sink, sacn_senders, order, serpentine, first):
    cfg = content_config(ports, order=order, serpentine=serpentine, first=first,
                         sacn_start_channel=5, artnet_enabled=False)
    p = _player(cfg, sink)
    try:
        stream = (np.arange(ROWS * COLS) * 7 + 3).astype(np.uint8)
        s = sacn_senders(ports[0])
        s[1].dmx_data = (0, 0, 0, 0) + tuple(int(v) for v in stream)
        expect = np.empty_like(stream)
        expect[stream_to_display(ROWS, COLS, order, serpentine, first)] = stream
        got = sink.wait_for(lambda f: np.array_equal(f, expect))
        assert np.array_equal(got, expect)
        assert p.status().source is ContentSource.SACN
        assert p.receivers[ContentSource.SACN].stats.accepted > 0
    finally:
        p.stop()


def test_sacn_display_over_two_universes(ports, sink, sacn_senders):
    rows, cols = 16, 40  # 640 pixels from channel 100 of universe 3: universes 3 and 4
    cfg = content_config(ports, sacn_universe=3, sacn_start_channel=100,
                         artnet_enabled=False)
    p = _player(cfg, sink, rows, cols)
    try:
        stream = (np.arange(rows * cols) % 251).astype(np.uint8)
        s = sacn_senders(ports[0], universes=(3, 4))
        first = 512 - 99
        s[3].dmx_data = (0,) * 99 + tuple(int(v) for v in stream[:first])
        s[4].dmx_data = tuple(int(v) for v in stream[first:])
        got = sink.wait_for(lambda f: np.array_equal(f, stream))
        assert got.shape == (rows * cols,)
    finally:
        p.stop()


def test_sacn_priority_htp_and_termination(ports, sink, sacn_senders):
    cfg = content_config(ports, artnet_enabled=False, hold_s=5.0)
    p = _player(cfg, sink)
    n = ROWS * COLS
    try:
        low = sacn_senders(ports[0], priority=100, name="low")
        high = sacn_senders(ports[0], priority=150, name="high")
        low[1].dmx_data = (200,) * n
        high[1].dmx_data = (10,) * n
        # the higher priority wins though its levels are lower
        sink.wait_for(lambda f: np.all(f == 10))
        time.sleep(0.3)
        assert np.all(sink.last() == 10)
        # the high sender ends its stream (three stream-terminated packets): the low one
        # takes over at once, not after hold_s or the source timeout
        t0 = time.monotonic()
        high.deactivate_output(1)
        sink.wait_for(lambda f: np.all(f == 200), timeout_s=2.0)
        assert time.monotonic() - t0 < 1.0
        # a second sender at the same priority: each channel its highest level (HTP)
        peer = sacn_senders(ports[0], priority=100, name="peer")
        a = np.zeros(n, np.uint8)
        a[::2] = 250
        peer[1].dmx_data = tuple(int(v) for v in a)
        sink.wait_for(lambda f: np.array_equal(f, np.maximum(a, 200)))
        assert p.receivers[ContentSource.SACN].stats.terminated >= 1
    finally:
        p.stop()


def test_artnet_frame_and_silence_hold(ports, sink):
    hold = 0.6
    cfg = content_config(ports, sacn_enabled=False, artnet_universe=3, hold_s=hold)
    p = _player(cfg, sink)
    art = StupidArtnet("127.0.0.1", 3, ROWS * COLS, 30, port=ports[1])
    try:
        levels = bytearray((np.arange(ROWS * COLS) * 5 % 256).astype(np.uint8).tobytes())
        art.set(levels)
        for _ in range(5):
            art.show()
            time.sleep(0.03)
        sink.wait_for(lambda f: f.tobytes() == bytes(levels))
        assert p.status().source is ContentSource.ARTNET
        # a script frame below it waits while the sender is live ...
        script = np.full(ROWS * COLS, 77, np.uint8)
        p.set_frame(script, hold_s=30)
        for _ in range(10):
            art.show()
            time.sleep(0.03)
        assert sink.last().tobytes() == bytes(levels)
        # ... and takes over hold_s after the sender went silent; frames keep their rate
        # through the hold and the takeover, and memory stays
        t_silent = time.monotonic()
        took, rate, growth = _through_silence(sink, t_silent, lambda f: np.all(f == 77))
        assert hold - 0.05 <= took <= hold + 0.25, took
        assert p.status().source is ContentSource.SCRIPT
        assert rate >= RATE_KEPT * FPS and growth <= RSS_GROWTH_MIB * 2**20, (rate, growth)
    finally:
        art.close()
        p.stop()


def test_sacn_silence_falls_back_to_idle_picture(ports, sink, sacn_senders, tmp_path):
    from PIL import Image

    idle = tmp_path / "idle.png"
    Image.new("RGB", (COLS, ROWS), (0, 90, 0)).save(idle)
    cfg = content_config(ports, artnet_enabled=False, hold_s=0.4, idle=idle, map="green")
    p = _player(cfg, sink)
    try:
        sink.wait_for(lambda f: np.all(f == 90))  # nothing live yet: the idle picture
        s = sacn_senders(ports[0])
        s[1].dmx_data = (33,) * (ROWS * COLS)
        sink.wait_for(lambda f: np.all(f == 33))
        s.stop()  # silent, not terminated
        took, rate, growth = _through_silence(sink, time.monotonic(), lambda f: np.all(f == 90))
        assert 0.3 <= took <= 0.8, took
        assert p.status().source is ContentSource.IDLE
        assert rate >= RATE_KEPT * FPS and growth <= RSS_GROWTH_MIB * 2**20, (rate, growth)
    finally:
        p.stop()


def test_receiver_port_in_use_says_how_to_fix(ports, sink):
    from grassd.daemon.content.receiver import ReceiverBindError

    cfg = content_config(ports, artnet_enabled=False)
    first = _player(cfg, sink)
    try:
        with pytest.raises(ReceiverBindError, match=r"\[content.sacn\] bind/port"):
            ContentPlayer(cfg, ROWS, COLS, sink)
    finally:
        first.stop()


def test_sacn_multicast_groups_joined(ports, sink, sacn_senders):
    """With multicast = true the receiver joins the universes' groups (239.255.0.7 and
    239.255.0.8 here) and takes the sender's multicast packets."""
    rows, cols = 16, 40  # two universes
    cfg = content_config(ports, artnet_enabled=False, sacn_multicast=True, sacn_universe=7)
    p = _player(cfg, sink, rows, cols)
    try:
        stream = (np.arange(rows * cols) % 199).astype(np.uint8)
        s = sacn_senders(ports[0], universes=(7, 8))
        for u in (7, 8):
            s[u].multicast = True
        s[7].dmx_data = tuple(int(v) for v in stream[:512])
        s[8].dmx_data = tuple(int(v) for v in stream[512:])
        sink.wait_for(lambda f: np.array_equal(f, stream))
    finally:
        p.stop()


def test_hold_zero_shows_packets_and_lets_go_at_once(ports, sink, sacn_senders):
    cfg = content_config(ports, artnet_enabled=False, hold_s=0.0, fps=30)
    p = _player(cfg, sink)
    try:
        p.set_frame(np.full(ROWS * COLS, 5, np.uint8), hold_s=60)
        sink.wait_for(lambda f: np.all(f == 5))
        s = sacn_senders(ports[0])
        s[1].dmx_data = (44,) * (ROWS * COLS)
        sink.wait_for(lambda f: np.all(f == 44))  # a live packet shows even without a hold
        s.stop()
        t0 = time.monotonic()
        sink.wait_for(lambda f: np.all(f == 5), timeout_s=3)
        assert time.monotonic() - t0 < 0.3
    finally:
        p.stop()

