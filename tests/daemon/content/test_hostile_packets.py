"""Malformed packets (a fuzz with a fixed seed and budget) and a flood of 10,000 packets/s
(junk, other universes, well-formed packets from ever new senders): each is dropped and
counted, never fatal, and neither the frame rate nor memory moves."""

from __future__ import annotations

import socket
import subprocess
import sys
import threading
import time

import numpy as np
from content_helpers import RATE_KEPT, RSS_GROWTH_MIB, content_config
from sacn.messages.data_packet import DataPacket
from stupidArtnet import StupidArtnet

from grassd.daemon.content.packets import (
    DmxPacket,
    PacketError,
    decode_artdmx,
    decode_e131,
)
from grassd.daemon.content.player import ContentPlayer
from grassd.daemon.content.status import ContentSource
from grassd.rigs.peak_memory import peak_rss_growth

ROWS, COLS = 4, 8
SEED = 52
BUDGET = 20_000  # mutations decoded directly
SENT = 3_000  # of them sent over UDP


def _valid_e131() -> bytes:
    """A data packet as the sACN library writes it."""
    p = DataPacket(cid=tuple(range(16)), sourceName="fuzz", universe=1,
                   dmxData=tuple(range(32)), priority=100, sequence=7)
    return bytes(p.getBytes())


def _valid_artdmx() -> bytes:
    """An ArtDmx packet as stupidArtnet writes it."""
    a = StupidArtnet("127.0.0.1", 0, 32, 30, port=9)  # never shown: only its packet
    a.set(bytearray(range(32)))
    packet = bytes(a.packet_header) + bytes(a.buffer)
    a.close()
    return packet


def _mutations(rng: np.random.Generator, base: bytes, n: int):
    for _ in range(n):
        b = bytearray(base)
        kind = rng.integers(5)
        if kind == 0:  # flip bytes
            for i in rng.integers(0, len(b), rng.integers(1, 6)):
                b[i] = int(rng.integers(256))
        elif kind == 1:  # cut
            b = b[:int(rng.integers(0, len(b)))]
        elif kind == 2:  # grow, up to an oversized datagram
            b += bytes(rng.integers(0, 256, int(rng.integers(1, 1500)), dtype=np.uint8))
        elif kind == 3:  # random bytes of a plausible size
            b = bytearray(rng.integers(0, 256, int(rng.integers(0, 700)), dtype=np.uint8))
        else:  # a header field set to an edge value
            i = int(rng.integers(0, min(len(b), 126)))
            b[i] = int(rng.choice([0, 1, 0x7F, 0x80, 0xFF]))
        yield bytes(b)


def test_decoders_accept_the_libraries_packets():
    p = decode_e131(_valid_e131())
    assert (p.universe, p.priority, p.sequence, p.name) == (1, 100, 7, "fuzz")
    assert p.data[:32] == bytes(range(32)) and len(p.data) == 512  # the library pads
    a = decode_artdmx(_valid_artdmx(), "127.0.0.1:1")
    assert (a.universe, a.data) == (0, bytes(range(32)))


def test_fuzz_decoders_raise_only_packet_errors():
    rng = np.random.default_rng(SEED)
    kinds = {"ok": 0, "dropped": 0}
    for base, decode in ((_valid_e131(), decode_e131),
                         (_valid_artdmx(), lambda b: decode_artdmx(b, "1.2.3.4:5"))):
        for data in _mutations(rng, base, BUDGET // 2):
            try:
                out = decode(data)
            except PacketError:
                kinds["dropped"] += 1
                continue
            assert isinstance(out, DmxPacket) and 1 <= len(out.data) <= 512
            kinds["ok"] += 1
    assert kinds["dropped"] > BUDGET // 2  # most mutations break the packet
    assert kinds["ok"] > 0  # some only changed levels


class ScriptFrames:
    """Sets a new script frame on ``player`` every ``1 / fps`` s from a thread of its own: a
    source that shows without sending a datagram, so the receivers count only what the test
    sends them."""

    def __init__(self, player: ContentPlayer, n_pixels: int, fps: float) -> None:
        self.player, self.n_pixels, self.period = player, n_pixels, 1.0 / fps
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        k, t = 0, time.monotonic()
        while not self._stop.is_set():
            k += 1
            self.player.set_frame(np.full(self.n_pixels, k % 256, np.uint8), hold_s=5.0)
            t += self.period
            self._stop.wait(max(0.0, t - time.monotonic()))

    def __enter__(self) -> ScriptFrames:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(5)


def test_fuzz_over_udp_counted_never_fatal(ports, sink, sacn_senders):
    """Fuzzed datagrams to both receivers while script frames change every period; the
    frames go to a capturing sink (the player's output, no controllers): every datagram is
    counted, frames keep at least 90 % of ``fps``, peak RSS grows at most 16 MiB, and a real
    sender's frame comes through after."""
    fps = 30
    cfg = content_config(ports, hold_s=0.2, fps=fps)
    p = ContentPlayer(cfg, ROWS, COLS, sink).start()
    rng = np.random.default_rng(SEED + 1)
    try:
        def fuzz() -> None:
            with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
                for base, port in ((_valid_e131(), ports[0]), (_valid_artdmx(), ports[1])):
                    for data in _mutations(rng, base, SENT // 2):
                        s.sendto(data, ("127.0.0.1", port))
                        time.sleep(0.0002)  # within the socket buffer: every one is counted

        with ScriptFrames(p, ROWS * COLS, fps):
            sink.wait_for(lambda f: f[0] > 0)
            time.sleep(0.2)
            t0 = time.monotonic()
            raised, seconds, growth = peak_rss_growth(fuzz, every_s=0.01)
            t1 = time.monotonic()
        assert raised is None, raised
        got = sink.rate(t0, t1)
        print(f"fuzz of {SENT} datagrams in {seconds:.2f} s: frames out {got:.1f}/s; "
              f"peak RSS +{growth / 2**20:.1f} MiB")
        assert got >= RATE_KEPT * fps
        assert growth <= RSS_GROWTH_MIB * 2**20
        deadline = time.monotonic() + 5
        stats = [r.stats for r in p.receivers.values()]
        while time.monotonic() < deadline and sum(st.datagrams for st in stats) < SENT:
            time.sleep(0.05)
        for st in stats:
            counted = (st.accepted + st.malformed + st.oversized + st.ignored + st.late
                       + st.refused + st.terminated)
            assert counted == st.datagrams == SENT // 2
            assert st.malformed + st.oversized > SENT // 4
        time.sleep(0.3)  # past hold_s of anything the fuzz got through
        # the receivers still work: a real sender's frame comes through
        snd = sacn_senders(ports[0], priority=200)
        snd[1].dmx_data = (123,) * (ROWS * COLS)
        sink.wait_for(lambda f: np.all(f == 123))
    finally:
        p.stop()


FLOOD = r"""
import os, socket, sys, time
from sacn.messages.data_packet import DataPacket
port, rate, seconds = int(sys.argv[1]), int(sys.argv[2]), float(sys.argv[3])

def sacn(universe, priority):  # a well-formed packet from a sender never seen before
    return bytes(DataPacket(cid=tuple(os.urandom(16)), sourceName="flood", universe=universe,
                            dmxData=(255,) * 32, priority=priority).getBytes())

fresh = [sacn(1, 0) for _ in range(512)]  # our universe, lowest priority, new senders
other = sacn(9, 100)  # a universe the display does not use
junk = [bytes(range(256)) * 2, b"\x00\x10\x00\x00ASC-E1.17\x00\x00\x00" + bytes(600),
        b"x" * 1400]
s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
t0 = time.monotonic(); n = 0
while time.monotonic() - t0 < seconds:
    target = int((time.monotonic() - t0) * rate)
    while n < target:
        k = n % 8
        data = fresh[n // 8 % 512] if k == 0 else other if k == 1 else junk[k % 3]
        s.sendto(data, ("127.0.0.1", port)); n += 1
    time.sleep(0.001)
print(n)
"""


def test_flood_keeps_frame_rate_and_memory(ports, sink, sacn_senders):
    """10,000 packets/s for 10 s beside a sender changing the frame every period; the frames
    go to a capturing sink (the player's output, no controllers): at least 90 % of ``fps``
    out, peak RSS at most 16 MiB over the RSS before the flood."""
    fps, seconds, rate = 30, 10.0, 10_000
    cfg = content_config(ports, fps=fps, artnet_enabled=False, hold_s=2.0)
    p = ContentPlayer(cfg, ROWS, COLS, sink).start()
    try:
        snd = sacn_senders(ports[0], fps=fps)
        k = [0]

        def step():
            k[0] += 1
            snd[1].dmx_data = (k[0] % 256,) * (ROWS * COLS)

        step()
        sink.wait_for(lambda f: f[0] == 1)
        flood = subprocess.Popen([sys.executable, "-c", FLOOD, str(ports[0]), str(rate),
                                  str(seconds)], stdout=subprocess.PIPE, text=True)
        t0 = time.monotonic()

        def during_flood() -> None:  # a live source changing every frame
            while flood.poll() is None:
                step()
                time.sleep(1 / fps)

        raised, _, growth = peak_rss_growth(during_flood, every_s=0.01)
        assert raised is None, raised
        t1 = time.monotonic()
        sent = int(flood.stdout.read())
        times = sink.times(t0 + 0.5)
        times = times[times <= t1]
        got = (len(times) - 1) / (times[-1] - times[0])
        st = p.receivers[ContentSource.SACN].stats
        print(f"flood {sent / seconds:.0f} packets/s for {t1 - t0:.1f} s; frames out "
              f"{got:.1f}/s; peak RSS +{growth / 2**20:.1f} MiB; counted {st.to_json()}")
        assert sent >= 0.9 * rate * seconds
        assert got >= RATE_KEPT * fps
        assert growth <= RSS_GROWTH_MIB * 2**20
        assert st.malformed + st.oversized >= 0.5 * sent  # the rest: the kernel's buffer
        assert st.refused > 0 and st.ignored > 0  # new senders beyond the cap; universe 9
        assert p.mergers[ContentSource.SACN].senders <= cfg.sacn.max_sources
        assert p.status().source is ContentSource.SACN
    finally:
        p.stop()
