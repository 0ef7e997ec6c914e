"""The C firmware answers like the Python reference, byte for byte, over long random request
sequences: transfers with chunks in any order, out of range, oversized, retransmitted; commits
with wrong or right CRCs and out-of-range values; levels and test patterns (PATTERN with good
and bad timeouts, pixels and lengths, PATTERN_END) in any order; unknown types, other
versions, bad payload lengths; the frame latch (STAGE_LEVEL in and out of range, SHOW to
the controller and broadcast, never answered); and power cycles (the posix process restarted
on its storage, the QEMU instance reset with its RAM storage kept, the model power-cycled).
The firmware is driven over its real pty (through the bus relay for QEMU); GET_POSITIONS is
left out (the implementations simulate different motors)."""

from __future__ import annotations

import os
import select
import time
import tty

import numpy as np
import pytest
from firmware_tiers import firmware_params

from grassd.firmware_proto.codec import Frame, encode_body_of, encode_frame
from grassd.firmware_proto.crc import crc32_iso_hdlc
from grassd.firmware_proto.framing import FrameReader, encode_body
from grassd.firmware_proto.messages import (
    GetStatus,
    Hello,
    Pattern,
    PatternEnd,
    SetLevel,
    Show,
    StageLevel,
    TableBegin,
    TableChunk,
    TableCommit,
)
from grassd.rigs.firmware import Controller, ControllerConfig
from grassd.rigs.sim_backends import open_bus

N_PIXELS = 3


class PtyPort:
    """Raw bytes to and from a posix firmware's pty."""

    def __init__(self, path: str) -> None:
        self.fd = os.open(path, os.O_RDWR | os.O_NOCTTY)
        tty.setraw(self.fd)
        self.reader = FrameReader()

    def ask(self, wire: bytes, timeout_s: float = 2.0) -> bytes | None:
        """Send one request; return the answer's wire bytes, or None if none comes."""
        os.write(self.fd, wire)
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            ready, _, _ = select.select([self.fd], [], [], 0.05)
            if ready:
                bodies = self.reader.feed(os.read(self.fd, 4096))
                if bodies:
                    (body,) = bodies
                    return encode_body(body)
        return None

    def close(self) -> None:
        os.close(self.fd)


def random_requests(rng: np.random.Generator, n: int):
    """(kind, wire bytes) pairs: requests for address 1, sometimes malformed, plus reboots."""
    tables = [rng.integers(0, 20001, (N_PIXELS, 256)).astype("<u2").tobytes(),
              rng.integers(0, 20001, 256).astype("<u2").tobytes(),
              np.full(256, 25000, dtype="<u2").tobytes()]  # over max_length_um
    seq = 1
    last = None
    for _ in range(n):
        r = rng.random()
        data = tables[rng.integers(0, 3)]
        tid = int(rng.integers(0, 3))
        crc = crc32_iso_hdlc(data) if rng.random() < 0.8 else int(rng.integers(0, 2**32))
        if r < 0.01:
            yield "reboot", b""
            continue
        if r < 0.03:  # a whole transfer, chunks in random order, then its COMMIT
            seq = (seq + 1) % 65536
            per_pixel = len(data) == N_PIXELS * 512
            yield "request", encode_frame(Frame(1, seq, TableBegin(
                tid, int(per_pixel), N_PIXELS if per_pixel else 1, len(data), crc)))
            for off in rng.permutation(np.arange(0, len(data), 200)):
                seq = (seq + 1) % 65536
                yield "request", encode_frame(Frame(1, seq, TableChunk(
                    tid, int(off), data[off:off + 200])))
            seq = (seq + 1) % 65536
            last = encode_frame(Frame(1, seq, TableCommit(tid, crc)))
            yield "request", last
            continue
        if r < 0.06 and last is not None:  # a retransmission: same seq, same bytes
            yield "request", last
            continue
        seq = (seq + 1) % 65536
        if r < 0.15:
            per_pixel = len(data) == N_PIXELS * 512
            msg = TableBegin(tid, int(per_pixel), N_PIXELS if per_pixel else 1, len(data), crc)
            if rng.random() < 0.1:
                msg = TableBegin(tid, int(rng.integers(0, 3)), int(rng.integers(0, 5)),
                                 int(rng.integers(0, 3000)), crc)
        elif r < 0.6:
            off = int(rng.integers(0, len(data) + 64))
            size = int(rng.integers(1, 300))
            chunk = (data + bytes(400))[off:off + size]
            msg = TableChunk(tid if rng.random() < 0.9 else 7, off, chunk)
        elif r < 0.72:
            msg = TableCommit(tid, crc)
        elif r < 0.8:
            msg = SetLevel(int(rng.integers(0, 4)), bytes(rng.integers(0, 256, int(
                rng.integers(1, 5))).astype(np.uint8)))
        elif r < 0.84:
            msg = GetStatus()
        elif r < 0.865:  # test patterns: long watchdogs (answers never depend on it anyway)
            count = int(rng.integers(1, 5))
            msg = Pattern(int(rng.choice([0, 3000, 65535])), int(rng.integers(0, 4)),
                          rng.integers(0, 21000, count).astype("<u2").tobytes())
        elif r < 0.88:
            msg = PatternEnd()
        elif r < 0.9:
            msg = Hello()
        elif r < 0.915:
            msg = StageLevel(int(rng.integers(0, 3)), int(rng.integers(0, 4)), bytes(
                rng.integers(0, 256, int(rng.integers(1, 5))).astype(np.uint8)))
        elif r < 0.93:
            address = int(rng.choice([0, 1]))  # broadcast: neither answers
            last = encode_frame(Frame(address, seq, Show(int(rng.integers(0, 3)))))
            yield "request", last
            continue
        else:  # malformed: unknown type, other version, wrong payload length
            body = bytearray(encode_body_of(Frame(1, seq, GetStatus())))
            kind = rng.integers(0, 3)
            if kind == 0:
                body[2] = int(rng.choice([0x00, 0x08, 0x10, 0x7F]))
            elif kind == 1:
                body[0] = 2
            else:
                body[2] = int(rng.integers(1, 8))
                body += bytes(rng.integers(0, 256, int(rng.integers(1, 30))).astype(np.uint8))
            last = encode_body(bytes(body))
            yield "request", last
            continue
        last = encode_frame(Frame(1, seq, msg))
        yield "request", last


@pytest.mark.parametrize(("firmware", "n"), [
    pytest.param(p.values[0], n, id=p.id, marks=p.marks)
    for p, n in zip(firmware_params("posix", "qemu"), (3000, 1500), strict=True)])
def test_c_firmware_answers_like_the_reference(tmp_path, firmware, n):
    rng = np.random.default_rng(11)
    model = Controller(ControllerConfig(address=1, n_pixels=N_PIXELS, uid=0x6A5D0001),
                       tmp_path / "model.eeprom", clock=lambda: 0.0)
    bus = open_bus(firmware, tmp_path / "c", [1], n_pixels=N_PIXELS,
                   link_path=tmp_path / "tty").start()
    port = PtyPort(bus.path)
    counts = {"request": 0, "reboot": 0, "nak": 0, "commit_ok": 0}
    try:
        for kind, wire in random_requests(rng, n):
            if kind == "reboot":
                port.close()
                bus.power_cycle()
                port = PtyPort(bus.path)
                model.power_cycle()
                counts["reboot"] += 1
                continue
            (body,) = FrameReader().feed(wire)
            expected = model.handle(body)
            got = port.ask(wire, 2.0 if expected is not None else 0.2)
            assert got == expected, (f"request {wire.hex()}: C answered "
                                     f"{got.hex() if got else None}, reference "
                                     f"{expected.hex() if expected else None}")
            counts["request"] += 1
            counts["nak"] += expected is not None and expected[3] == 0x91
            counts["commit_ok"] += body[2] == 0x05 and expected[3] == 0x90
        # and what each has stored is the same table
        assert np.array_equal(np.asarray(model.active_table()),
                              np.asarray(bus.controllers[0].active_table()))
    finally:
        port.close()
        bus.stop()
        model.close()
    print(f"differential: {counts}")
    assert counts["reboot"] >= 5 and counts["commit_ok"] >= 5 and counts["nak"] > n / 6
