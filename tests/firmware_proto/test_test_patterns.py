"""Test patterns (PROTOCOL.md §3): PATTERN drives pixels to raw lengths bypassing
the table, PATTERN_END and the watchdog return them to normal display, a power cycle forgets
the pattern; INFO's features bit, old 16-byte INFO; the client's show_pattern / end_pattern.

The state machine is checked on the Python model with a hand-moved clock; the client tests run
over real ptys against the model, the posix C process and the QEMU image (the ``bus`` fixture),
where the watchdog must act with no frame from the host at all."""

from __future__ import annotations

import itertools
import struct
import time

import numpy as np
import pytest
from firmware_tiers import CLEAN_LINK, firmware_params

from grassd.firmware_proto.client import (
    ControllerClient,
    ControllerUnsupported,
    RetryPolicy,
)
from grassd.firmware_proto.codec import Frame, decode_frame, encode_body_of
from grassd.firmware_proto.errors import FrameError, NakError, TableError
from grassd.firmware_proto.framing import decode_body
from grassd.firmware_proto.messages import (
    FEATURE_PATTERNS,
    Ack,
    Hello,
    Info,
    Message,
    MsgType,
    Nak,
    NakCode,
    Pattern,
    PatternEnd,
    SetLevel,
    TableBegin,
    TableChunk,
    TableCommit,
    TableKind,
)
from grassd.firmware_proto.tables import chunk_spans, table_bytes, table_crc
from grassd.rigs.firmware import Controller, ControllerConfig
from grassd.rigs.sim_backends import open_bus
from grassd.rigs.simulator import SimulatedBus, make_controllers

_seq = itertools.count(1)
TABLE = (np.arange(256) * 40).astype(np.uint16)  # level l -> 40 l um


class Clock:
    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


def ask(ctl: Controller, msg: Message | bytes, msg_type: int | None = None) -> Message | None:
    """Send ``msg`` (or a raw payload of ``msg_type``) to controller 1; its decoded answer."""
    if isinstance(msg, bytes):
        body = encode_body_of(Frame(1, next(_seq), Hello()))
        body = body[:2] + bytes([msg_type]) + body[3:5] + msg
    else:
        body = encode_body_of(Frame(1, next(_seq), msg))
    wire = ctl.handle(body)
    return None if wire is None else decode_frame(wire[:-1]).message


def lengths(*um: int) -> bytes:
    return np.asarray(um, dtype="<u2").tobytes()


def push(ctl: Controller, table: np.ndarray, tid: int = 7) -> None:
    data = table_bytes(table)
    assert ask(ctl, TableBegin(tid, TableKind.GLOBAL, 1, len(data), table_crc(table))) == \
        Ack(MsgType.TABLE_BEGIN)
    for o, k in chunk_spans(len(data), 256):
        assert isinstance(ask(ctl, TableChunk(tid, o, data[o:o + k])), Ack)
    assert ask(ctl, TableCommit(tid, table_crc(table))) == Ack(MsgType.TABLE_COMMIT)


def targets(ctl: Controller) -> list[int]:
    return ctl.targets_um().astype(int).tolist()


@pytest.fixture
def clock():
    return Clock()


@pytest.fixture
def ctl(tmp_path, clock):
    c = Controller(ControllerConfig(address=1, n_pixels=4), tmp_path / "c.eeprom", clock=clock)
    yield c
    c.close()


# --- the state machine (model, hand-moved clock) ---------------------------------------------

def test_pattern_drives_pixels_to_raw_lengths_bypassing_the_table(ctl):
    # without a table (SET_LEVEL would be NAK NO_TABLE) ...
    assert ask(ctl, Pattern(50, 1, lengths(5000, 20000))) == Ack(MsgType.PATTERN)
    assert targets(ctl) == [0, 5000, 20000, 0] and ctl.in_pattern
    # ... and with one: the lengths are raw micrometres, not levels through the table
    push(ctl, TABLE)
    assert ask(ctl, Pattern(50, 0, lengths(255, 3))) == Ack(MsgType.PATTERN)
    assert targets(ctl) == [255, 3, 20000, 0]  # pixels not named keep their targets


def test_pattern_end_restores_table_level_and_set_level_waits_for_it(ctl):
    push(ctl, TABLE)
    assert ask(ctl, SetLevel(0, bytes([10, 20, 30, 40]))) == Ack(MsgType.SET_LEVEL)
    assert ask(ctl, Pattern(50, 2, lengths(1234))) == Ack(MsgType.PATTERN)
    assert targets(ctl) == [400, 800, 1234, 1600]
    # levels and a new table during the pattern: accepted, no pixel moves
    assert ask(ctl, SetLevel(0, bytes([1, 2, 3, 4]))) == Ack(MsgType.SET_LEVEL)
    assert targets(ctl) == [400, 800, 1234, 1600]
    assert ask(ctl, PatternEnd()) == Ack(MsgType.PATTERN_END)
    assert targets(ctl) == [40, 80, 120, 160] and not ctl.in_pattern  # table[level], at once
    assert ask(ctl, PatternEnd()) == Ack(MsgType.PATTERN_END)  # idempotent
    assert targets(ctl) == [40, 80, 120, 160]
    # a commit during a pattern: as without one, targets change with the next SET_LEVEL
    assert ask(ctl, Pattern(50, 0, lengths(9))) == Ack(MsgType.PATTERN)
    push(ctl, TABLE // 2, tid=8)
    assert targets(ctl) == [9, 80, 120, 160]
    assert ask(ctl, SetLevel(1, bytes([5]))) == Ack(MsgType.SET_LEVEL)
    assert targets(ctl) == [9, 80, 120, 160]
    assert ask(ctl, PatternEnd()) == Ack(MsgType.PATTERN_END)
    assert targets(ctl) == [40, 100, 120, 160]


def test_watchdog_returns_to_normal_display_without_any_host_frame(ctl, clock):
    assert ask(ctl, Pattern(25, 0, lengths(4000))) == Ack(MsgType.PATTERN)  # 2.5 s
    clock.t += 2.4999
    assert ctl.in_pattern and targets(ctl) == [4000, 0, 0, 0]
    clock.t += 0.0001
    assert not ctl.in_pattern and targets(ctl) == [0, 0, 0, 0]
    # motion follows the deadline exactly: 20 mm/s, out for 2.5 s (4 mm reached), back 1 s
    clock.t += 10.0
    assert ctl.positions_um().tolist() == [0, 0, 0, 0]


def test_each_pattern_frame_rearms_the_watchdog(ctl, clock):
    assert ask(ctl, Pattern(10, 0, lengths(100))) == Ack(MsgType.PATTERN)
    clock.t += 0.9
    assert ask(ctl, Pattern(10, 1, lengths(200))) == Ack(MsgType.PATTERN)
    clock.t += 0.9
    assert ctl.in_pattern and targets(ctl) == [100, 200, 0, 0]
    clock.t += 0.1
    assert not ctl.in_pattern and targets(ctl) == [0, 0, 0, 0]


def test_refused_pattern_changes_nothing_and_does_not_rearm(ctl, clock):
    assert ask(ctl, Pattern(10, 0, lengths(100))) == Ack(MsgType.PATTERN)
    clock.t += 0.5
    assert ask(ctl, Pattern(10, 0, lengths(1, 20001))) == Nak(MsgType.PATTERN,
                                                               NakCode.VALUE_RANGE, 1)
    clock.t += 0.5
    assert not ctl.in_pattern and targets(ctl) == [0, 0, 0, 0]


def test_power_cycle_in_pattern_mode_comes_back_in_normal_display(ctl, clock):
    push(ctl, TABLE)
    assert ask(ctl, SetLevel(0, bytes([10, 10, 10, 10]))) == Ack(MsgType.SET_LEVEL)
    clock.t += 5
    assert ask(ctl, Pattern(600, 0, lengths(3000, 3000))) == Ack(MsgType.PATTERN)
    clock.t += 0.05  # the motors moved 1 mm towards the pattern
    ctl.power_cycle()
    assert not ctl.in_pattern
    assert targets(ctl) == [1400, 1400, 400, 400]  # boot: motors hold where they are
    assert ask(ctl, SetLevel(0, bytes([20, 20]))) == Ack(MsgType.SET_LEVEL)
    assert targets(ctl) == [800, 800, 400, 400]  # levels move pixels again at once


@pytest.mark.parametrize(("msg", "nak"), [
    (Pattern(10, 0, lengths(20000, 20001, 30000)), (NakCode.VALUE_RANGE, 1)),
    (Pattern(10, 3, lengths(1, 2)), (NakCode.BAD_PIXEL, 4)),
    (Pattern(10, 0xFFFF, lengths(1)), (NakCode.BAD_PIXEL, 4)),
    (Pattern(0, 0, lengths(1)), (NakCode.BAD_PAYLOAD, 0)),
    (struct.pack("<HH", 10, 0) + b"\x01\x02\x03", (NakCode.BAD_PAYLOAD, 7)),  # odd bytes
    (struct.pack("<HH", 10, 0), (NakCode.BAD_PAYLOAD, 4)),  # no length
    (b"\x01", (NakCode.BAD_PAYLOAD, 1)),
])
def test_pattern_naks(ctl, msg, nak):
    got = ask(ctl, msg, MsgType.PATTERN)
    assert got == Nak(MsgType.PATTERN, *nak)
    assert not ctl.in_pattern and targets(ctl) == [0, 0, 0, 0]


def test_pattern_end_with_a_payload_is_bad_payload(ctl):
    assert ask(ctl, b"\x00", MsgType.PATTERN_END) == Nak(MsgType.PATTERN_END,
                                                         NakCode.BAD_PAYLOAD, 1)


def test_controller_before_patterns_answers_unknown_type_and_short_info(tmp_path):
    old = Controller(ControllerConfig(address=1, n_pixels=4, patterns=False),
                     tmp_path / "old.eeprom", clock=Clock())
    wire = old.handle(encode_body_of(Frame(1, 1, Hello())))
    assert len(decode_body(wire[:-1])) == 5 + 16  # header and the old INFO (CRC checked)
    info = decode_frame(wire[:-1]).message
    assert info.features == 0 and not info.supports_patterns
    for msg in (Pattern(10, 0, lengths(1)), PatternEnd()):
        assert ask(old, msg) == Nak(msg.TYPE, NakCode.UNKNOWN_TYPE, len(msg.pack()))
    old.close()


# --- INFO -------------------------------------------------------------------------------------

def test_info_decodes_the_old_16_byte_payload_and_the_new_one():
    new = Info(1, 1, 0, 0, 0x6A5D0001, 16, 16, 256, 20000, FEATURE_PATTERNS)
    payload = new.pack()
    assert len(payload) == 18 and payload[16:] == b"\x01\x00"
    assert Info.unpack(payload) == new and new.supports_patterns
    old = Info.unpack(payload[:16])
    assert old.features == 0 and not old.supports_patterns
    assert old == Info(1, 1, 0, 0, 0x6A5D0001, 16, 16, 256, 20000)
    # later fields after features are ignored by this host
    assert Info.unpack(payload + b"\xAA\xBB\xCC") == new
    # and whatever decodes re-encodes to the bytes received (hypothesis found a 24-byte one)
    for received in (payload[:16], payload + b"\xAA\xBB\xCC", bytes(24)):
        assert Info.unpack(received).pack() == received
    for bad in (payload[:15], payload[:17], b""):
        with pytest.raises(FrameError):
            Info.unpack(bad)


# --- the client over real ptys: model, posix C process, QEMU image ----------------------------

FAST = RetryPolicy(timeout_s=0.3, retries=2, backoff_s=0.005)


@pytest.fixture(params=firmware_params("model", "posix", "qemu"))
def bus(request, tmp_path):
    """Controllers 1 and 2 (4 pixels each) on one pty."""
    with open_bus(request.param, tmp_path / "state", [1, 2], n_pixels=4,
                  link_path=tmp_path / "ttyGRASS0") as b:
        b.firmware = request.param
        yield b
        assert b.errors == 0


def test_client_shows_a_pattern_and_ends_it(bus):
    with ControllerClient(bus.path, policy=CLEAN_LINK, seed=3) as c:
        assert c.hello(1).supports_patterns
        c.push_table(1, TABLE)
        c.set_levels(1, [10, 20, 30, 40])
        c.show_pattern(1, [5000, 20000], first_pixel=1, timeout_s=30)
        assert c.read_positions(1)[:, 1].tolist() == [400, 5000, 20000, 1600]
        assert c.read_positions(2)[:, 1].tolist() == [0, 0, 0, 0]  # only the addressed one
        c.set_levels(1, [1, 2, 3, 4])  # held until the pattern ends
        assert c.read_positions(1)[:, 1].tolist() == [400, 5000, 20000, 1600]
        c.end_pattern(1)
        assert c.read_positions(1)[:, 1].tolist() == [40, 80, 120, 160]
        c.end_pattern(1)  # idempotent
        with pytest.raises(TableError):
            c.show_pattern(1, [20001], timeout_s=1)  # over max_length_um: nothing sent
        with pytest.raises(TableError):
            c.show_pattern(1, [1, 2], first_pixel=3, timeout_s=1)
        with pytest.raises(ValueError):
            c.show_pattern(1, [1], timeout_s=0)
        with pytest.raises(ValueError):
            c.show_pattern(1, [1], timeout_s=7000)
        assert c.read_positions(1)[:, 1].tolist() == [40, 80, 120, 160]
        assert c.retransmissions == 0


def test_watchdog_returns_to_normal_display_with_no_host_frame(bus):
    """The pattern ends by itself: after the timeout the motors have already driven back to
    normal display when the host looks again (a GET_POSITIONS would end an expired pattern
    itself, but could not have moved the motors back before answering)."""
    with ControllerClient(bus.path, policy=FAST, seed=4) as c:
        c.show_pattern(1, [4000, 4000], first_pixel=1, timeout_s=1.5)
        t0 = time.monotonic()
        assert c.read_positions(1)[:, 1].tolist() == [0, 4000, 4000, 0]
        time.sleep(max(0.0, t0 + 0.7 - time.monotonic()))
        mid = c.read_positions(1)
        if time.monotonic() - t0 < 1.4:  # (a loaded machine may answer later than that)
            assert mid[:, 1].tolist() == [0, 4000, 4000, 0]
            assert mid[1, 0] > 3500  # reached the pattern (model 20 mm/s, C motors 60 mm/s)
        time.sleep(max(0.0, t0 + 3.5 - time.monotonic()))  # 1.5 s, then 2 s to drive back
        after = c.read_positions(1)
        assert after[:, 1].tolist() == [0, 0, 0, 0]
        assert np.abs(after[:, 0].astype(int)).max() <= 100, after


def test_power_cycle_in_pattern_mode_comes_back_in_normal_display_on_the_line(bus):
    with ControllerClient(bus.path, policy=FAST, seed=5) as c:
        c.push_table(1, TABLE)
        c.show_pattern(1, [2000, 2000, 2000, 2000], timeout_s=600)
    if bus.firmware == "model":
        for ctl in bus.controllers:
            ctl.power_cycle()
    else:
        bus.power_cycle()
    with ControllerClient(bus.path, policy=FAST, seed=6) as c:
        c.set_levels(1, [5, 6, 7, 8])  # moves pixels at once: no pattern holds them
        assert c.read_positions(1)[:, 1].tolist() == [200, 240, 280, 320]


def test_client_refuses_patterns_on_a_controller_without_them(tmp_path):
    ctrls = make_controllers(tmp_path / "old", [1], n_pixels=4, patterns=False)
    with SimulatedBus(ctrls, link_path=tmp_path / "ttyOLD") as b, \
            ControllerClient(b.path, policy=FAST, seed=7) as c:
        info = c.hello(1)
        assert info.features == 0 and not info.supports_patterns
        with pytest.raises(ControllerUnsupported, match="no test patterns"):
            c.show_pattern(1, [1000], timeout_s=5)
        with pytest.raises(ControllerUnsupported):
            c.end_pattern(1)
        # what the refusal saves: the old controller answers the frame NAK UNKNOWN_TYPE
        reply = c.request(1, PatternEnd())
        assert reply == Nak(MsgType.PATTERN_END, NakCode.UNKNOWN_TYPE, 0)
        assert c.read_positions(1, 0, 1)[0, 1] == 0


def test_client_splits_long_patterns_into_frames(tmp_path):
    ctrls = make_controllers(tmp_path / "big", [1], n_pixels=1200)
    with SimulatedBus(ctrls, link_path=tmp_path / "ttyBIG") as b, \
            ControllerClient(b.path, policy=FAST, seed=8) as c:
        want = np.arange(1100) * 10 % 20001
        c.show_pattern(1, want, first_pixel=50, timeout_s=30)
        got = b.controllers[0].targets_um()
        assert got[50:1150].astype(int).tolist() == want.tolist()
        assert not got[:50].any() and not got[1150:].any()
        with pytest.raises(NakError) as exc:  # a NAK from the controller is a NakError
            c._expect(1, Pattern(10, 0, lengths(20001)), Ack)
        assert exc.value.code == NakCode.VALUE_RANGE and exc.value.detail == 0

