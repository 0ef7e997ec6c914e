"""The controller state machine without a serial line: NAKs, idempotence, power cuts, motion."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from hypothesis import event
from hypothesis import settings as _settings
from hypothesis import strategies as _st
from hypothesis.stateful import RuleBasedStateMachine, initialize, invariant, rule

from grassd.firmware_proto.codec import Frame, decode_frame, encode_body_of, encode_frame
from grassd.firmware_proto.messages import (
    NO_BANK,
    Ack,
    GetPositions,
    GetStatus,
    Hello,
    Info,
    Message,
    Nak,
    NakCode,
    SetLevel,
    TableBegin,
    TableChunk,
    TableCommit,
    TableKind,
    TableStatus,
)
from grassd.firmware_proto.tables import chunk_spans, table_bytes, table_crc
from grassd.rigs.eeprom import BankStore
from grassd.rigs.firmware import Controller, ControllerConfig

_seq = itertools.count(1)


class Clock:
    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


def ask(ctl: Controller, msg: Message, seq: int | None = None, address: int = 1) -> Message | None:
    body = encode_body_of(Frame(address, next(_seq) if seq is None else seq, msg))
    wire = ctl.handle(body)
    return None if wire is None else decode_frame(wire[:-1]).message


def transfer(ctl: Controller, table: np.ndarray, tid: int, chunk: int = 200) -> list[Message]:
    data = table_bytes(table)
    kind, n = (TableKind.GLOBAL, 1) if table.ndim == 1 else (TableKind.PER_PIXEL, len(table))
    out = [ask(ctl, TableBegin(tid, kind, n, len(data), table_crc(table)))]
    out += [ask(ctl, TableChunk(tid, o, data[o:o + k])) for o, k in chunk_spans(len(data), chunk)]
    out.append(ask(ctl, TableCommit(tid, table_crc(table))))
    return out


@pytest.fixture
def ctl(tmp_path):
    c = Controller(ControllerConfig(address=1, n_pixels=4), tmp_path / "c.eeprom", clock=Clock())
    yield c
    c.close()


def table(seed: int, shape=(256,)) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 20001, shape).astype(np.uint16)


def test_transfer_commit_persist_and_reload(ctl, tmp_path):
    st = ask(ctl, GetStatus())
    assert isinstance(st, TableStatus) and st.active_bank == NO_BANK and not st.has_table
    info = ask(ctl, Hello())
    assert isinstance(info, Info) and info.n_pixels == 4 and info.max_length_um == 20000
    a = table(1)
    assert all(isinstance(r, Ack) for r in transfer(ctl, a, 11))
    st = ask(ctl, GetStatus())
    assert (st.table_id, st.table_crc, st.generation, st.kind) == (11, table_crc(a), 1, 0)
    ctl.power_cycle()
    assert np.array_equal(ctl.active_table(), a)
    other = Controller(ctl.config, tmp_path / "c.eeprom")  # a fresh boot from the same file
    assert np.array_equal(other.active_table(), a)
    other.close()
    b = table(2, (4, 256))
    assert all(isinstance(r, Ack) for r in transfer(ctl, b, 12))
    st = ask(ctl, GetStatus())
    assert (st.table_id, st.generation, st.kind, st.n_tables) == (12, 2, 1, 4)
    assert st.active_bank == 1  # the first commit went to bank 0, this one to bank 1
    ctl.power_cycle()
    assert np.array_equal(ctl.active_table(), b)


def test_naks(ctl):
    a = table(3)
    data, crc = table_bytes(a), table_crc(a)

    def nak(msg):
        r = ask(ctl, msg)
        assert isinstance(r, Nak), r
        return NakCode(r.error), r.detail

    assert nak(TableChunk(5, 0, b"\x00"))[0] == NakCode.NO_TRANSFER
    assert nak(TableCommit(5, crc))[0] == NakCode.NO_TRANSFER
    assert nak(TableBegin(5, 7, 1, 512, crc)) == (NakCode.BAD_KIND, 4)
    assert nak(TableBegin(5, TableKind.PER_PIXEL, 3, 1536, crc)) == (NakCode.BAD_KIND, 4)
    assert nak(TableBegin(5, TableKind.GLOBAL, 1, 500, crc))[0] == NakCode.BAD_KIND
    assert nak(SetLevel(0, b"\x01"))[0] == NakCode.NO_TABLE
    assert isinstance(ask(ctl, TableBegin(5, TableKind.GLOBAL, 1, 512, crc)), Ack)
    assert nak(TableChunk(5, 500, bytes(20))) == (NakCode.OUT_OF_RANGE, 512)
    assert nak(TableChunk(5, 0, bytes(257))) == (NakCode.TOO_LARGE, 256)
    assert nak(TableChunk(6, 0, bytes(2)))[0] == NakCode.NO_TRANSFER
    assert isinstance(ask(ctl, TableChunk(5, 0, data[:256])), Ack)
    assert nak(TableCommit(5, crc)) == (NakCode.INCOMPLETE, 256)
    assert isinstance(ask(ctl, TableChunk(5, 256, bytes(256))), Ack)  # wrong data
    code, detail = nak(TableCommit(5, crc))
    assert code == NakCode.CRC_MISMATCH and detail == table_crc(
        np.frombuffer(data[:256] + bytes(256), "<u2"))
    assert nak(TableChunk(5, 0, b"\x00"))[0] == NakCode.NO_TRANSFER  # staging was discarded
    too_long = np.full(256, 20001, np.uint16)
    msgs = transfer(ctl, too_long, 9)
    assert NakCode(msgs[-1].error) == NakCode.VALUE_RANGE and msgs[-1].detail == 0
    assert not ask(ctl, GetStatus()).has_table  # nothing was ever committed
    transfer(ctl, a, 5)
    assert nak(SetLevel(3, b"\x01\x02")) == (NakCode.BAD_PIXEL, 4)
    assert nak(GetPositions(0, 0))[0] == NakCode.BAD_PAYLOAD
    assert nak(GetPositions(2, 3)) == (NakCode.BAD_PIXEL, 4)
    # unknown type, malformed payload, other protocol version
    body = encode_body_of(Frame(1, 77, GetStatus()))
    r = decode_frame(ctl.handle(body[:2] + b"\x33" + body[3:])[:-1]).message
    assert (r.request_type, r.error) == (0x33, NakCode.UNKNOWN_TYPE)
    r = decode_frame(ctl.handle(body + b"\x01")[:-1]).message
    assert (r.error, r.detail) == (NakCode.BAD_PAYLOAD, 1)
    r = decode_frame(ctl.handle(b"\x02" + body[1:])[:-1]).message
    assert (r.error, r.detail) == (NakCode.UNSUPPORTED_VERSION, 1)


def test_ignores_other_addresses_and_responses(ctl):
    assert ask(ctl, Hello(), address=2) is None
    assert ask(ctl, Ack(1)) is None
    assert ctl.handle(b"\x01") is None


def test_retransmissions_are_idempotent(ctl):
    a, b = table(4), table(5)
    transfer(ctl, a, 1)
    data, crc = table_bytes(b), table_crc(b)
    begin = TableBegin(2, TableKind.GLOBAL, 1, 512, crc)
    assert isinstance(ask(ctl, begin, seq=100), Ack)
    assert isinstance(ask(ctl, TableChunk(2, 0, data[:256]), seq=101), Ack)
    # a retransmitted BEGIN after chunks arrived (new seq: the cache cannot help) keeps them
    assert isinstance(ask(ctl, begin, seq=102), Ack)
    assert ask(ctl, GetStatus()).staged_bytes == 256
    assert isinstance(ask(ctl, TableChunk(2, 256, data[256:]), seq=103), Ack)
    first = ask(ctl, TableCommit(2, crc), seq=104)
    again = ask(ctl, TableCommit(2, crc), seq=104)  # same seq, same bytes: cached answer
    assert isinstance(first, Ack) and again == first
    assert ask(ctl, GetStatus()).generation == 2
    ctl.power_cycle()  # the cache is gone, the commit is still acknowledged, not redone
    assert isinstance(ask(ctl, TableCommit(2, crc), seq=104), Ack)
    assert ask(ctl, GetStatus()).generation == 2
    # a stale commit of the old table is refused rather than re-activating it
    assert NakCode(ask(ctl, TableCommit(1, table_crc(a))).error) == NakCode.NO_TRANSFER
    assert np.array_equal(ctl.active_table(), b)


def test_power_cut_in_every_write_leaves_old_or_new_table(tmp_path):
    """Cut power inside each EEPROM write of a transfer (at its first, middle and last byte):
    after reboot the active table is exactly the old one or exactly the new one."""
    a, b = table(6), table(7)
    outcomes = {"old": 0, "new": 0}
    cfg = ControllerConfig(address=1, n_pixels=2)
    for k in range(8):
        for where in ("first", "middle", "last"):
            path = tmp_path / f"c{k}{where}.eeprom"
            ctl = Controller(cfg, path, clock=Clock())
            transfer(ctl, a, 1, chunk=128)
            writes = ctl.eeprom.writes

            def hook(offset, data, k=k, where=where, writes=writes, ctl=ctl):
                if ctl.eeprom.writes - writes != k:
                    return None
                return {"first": 0, "middle": len(data) // 2, "last": len(data) - 1}[where]

            ctl.eeprom.tear_hook = hook
            transfer(ctl, b, 2, chunk=128)  # 1 invalidate + 4 chunk writes + 1 header write
            ctl.eeprom.tear_hook = None
            fresh = Controller(cfg, path)
            for c in (ctl, fresh):
                active = c.active_table()
                assert np.array_equal(active, a) or np.array_equal(active, b)
            outcomes["new" if np.array_equal(fresh.active_table(), b) else "old"] += 1
            bank, header = BankStore(fresh.eeprom, cfg.capacity).select_active()
            assert header is not None and header.data_crc == table_crc(fresh.active_table())
            ctl.close()
            fresh.close()
    assert outcomes["new"] == 3 * 2  # writes 6, 7 do not exist: no cut, new table
    assert outcomes["old"] == 3 * 6  # every cut up to and including the header write


def test_boot_delay_ignores_the_bus(tmp_path):
    clock = Clock()
    c = Controller(ControllerConfig(address=1, boot_s=0.5), tmp_path / "e", clock=clock)
    assert ask(c, Hello()) is None
    clock.t = 0.6
    assert isinstance(ask(c, Hello()), Info)
    c.close()


def test_motion_is_speed_limited_and_encoder_quantised(tmp_path):
    clock = Clock()
    cfg = ControllerConfig(address=1, n_pixels=3, speed_um_s=10_000, encoder_um=12.5)
    c = Controller(cfg, tmp_path / "e", clock=clock)
    per_pixel = np.stack([np.arange(256) * 50, np.arange(256) * 20, np.full(256, 7)])
    transfer(c, per_pixel.astype(np.uint16), 3)
    assert isinstance(ask(c, SetLevel(0, bytes([200, 200, 9]))), Ack)
    clock.t = 0.5
    pos = c.positions_um()
    assert pos[0] == 5000 and pos[1] == 4000 and pos[2] == 12  # 7 um reads as one 12.5 um count
    clock.t = 2.0
    pairs = ask(c, GetPositions(0, 3)).pairs()
    assert pairs == [(10000, 10000), (4000, 4000), (12, 7)]
    clock.t = 2.2
    ask(c, SetLevel(0, b"\x00"))
    clock.t = 2.3
    assert c.positions_um()[0] == 9000  # moving back at 10 mm/s
    c.power_cycle()  # motors stop where they are
    clock.t = 5.0
    assert c.positions_um()[0] == 9000
    c.close()


def test_wire_answer_is_a_valid_frame(ctl):
    wire = ctl.handle(encode_body_of(Frame(1, 5, Hello())))
    assert wire == encode_frame(decode_frame(wire[:-1]))


# --- stateful property test ----------------------------------------------------------------


_CANDIDATES = [table(100 + i) for i in range(3)]
_CUT = _st.one_of(_st.none(), _st.integers(0, 23))  # byte of the 24-byte header write


class FirmwareMachine(RuleBasedStateMachine):
    """Random interleavings of BEGIN / CHUNK / COMMIT, repeated frames, corrupt chunks, power
    cuts (clean and inside an EEPROM write): the active table is always exactly one that was
    committed, and an acknowledged COMMIT makes exactly that table active."""

    @initialize()
    def setup(self):
        import tempfile

        self.tmp = tempfile.TemporaryDirectory()
        self.ctl = Controller(ControllerConfig(address=1, n_pixels=1, max_chunk=96),
                              f"{self.tmp.name}/e.eeprom", clock=Clock())
        self.possible = [None]  # tables that may legitimately be active now
        self.cut_next_write_at: int | None = None
        self.ctl.eeprom.tear_hook = self._tear

    def teardown(self):
        if hasattr(self, "ctl"):
            self.ctl.close()
            self.tmp.cleanup()

    def _tear(self, offset, data):
        cut, self.cut_next_write_at = self.cut_next_write_at, None
        return None if cut is None else min(cut, len(data) - 1)

    def _send(self, msg, twice=False):
        """Send (maybe twice, as a retransmission); return the last answer."""
        body = encode_body_of(Frame(1, next(_seq), msg))
        reply = None
        for _ in range(2 if twice else 1):
            wire = self.ctl.handle(body)
            reply = None if wire is None else decode_frame(wire[:-1]).message
        return reply

    def _commit(self, k, tid, twice, cut=None):
        t = _CANDIDATES[k]
        boots = self.ctl.boots
        if cut is not None:
            self.cut_next_write_at = cut  # power fails inside the header write, if it happens
        reply = self._send(TableCommit(tid, table_crc(t)), twice)
        if isinstance(reply, Ack):
            assert np.array_equal(self.ctl.active_table(), t)
            assert ask(self.ctl, GetStatus()).table_id == tid
            self.possible = [t]
            event("commit acknowledged")
        elif self.ctl.boots != boots:  # power failed inside this commit: old or new
            self.possible = self.possible + [t]
            event("power cut inside a commit")

    @rule(k=_st.integers(0, 2), tid=_st.integers(0, 3), twice=_st.booleans())
    def begin(self, k, tid, twice):
        self._send(TableBegin(tid, TableKind.GLOBAL, 1, 512, table_crc(_CANDIDATES[k])), twice)

    @rule(k=_st.integers(0, 2), tid=_st.integers(0, 3), start=_st.integers(0, 511),
          length=_st.integers(1, 96), corrupt=_st.booleans(), twice=_st.booleans())
    def chunk(self, k, tid, start, length, corrupt, twice):
        data = table_bytes(_CANDIDATES[k])[start:start + length]
        if corrupt:
            data = bytes([data[0] ^ 0xFF]) + data[1:]
        self._send(TableChunk(tid, start, data), twice)

    @rule(k=_st.integers(0, 2), tid=_st.integers(0, 3),
          skip=_st.one_of(_st.just(-1), _st.integers(0, 5)),
          corrupt=_st.one_of(_st.just(-1), _st.integers(0, 5)),
          commit=_st.booleans(), twice=_st.booleans(), cut=_CUT)
    def transfer(self, k, tid, skip, corrupt, commit, twice, cut):
        """A whole transfer, maybe with one chunk left out or corrupted, maybe committed."""
        data = table_bytes(_CANDIDATES[k])
        self._send(TableBegin(tid, TableKind.GLOBAL, 1, 512, table_crc(_CANDIDATES[k])))
        for i, (o, n) in enumerate(chunk_spans(512, 96)):
            piece = data[o:o + n]
            if i == corrupt:
                piece = bytes([piece[0] ^ 0x55]) + piece[1:]
            if i != skip:
                self._send(TableChunk(tid, o, piece), twice)
        if commit:
            self._commit(k, tid, twice, cut)

    @rule(k=_st.integers(0, 2), tid=_st.integers(0, 3), twice=_st.booleans(), cut=_CUT)
    def commit(self, k, tid, twice, cut):
        self._commit(k, tid, twice, cut)

    @rule(at=_st.integers(0, 600))
    def arm_power_cut(self, at):
        self.cut_next_write_at = at

    @rule()
    def power_cycle(self):
        self.ctl.power_cycle()

    @invariant()
    def active_is_a_committed_table(self):
        if not hasattr(self, "ctl"):
            return
        active = self.ctl.active_table()
        assert any((p is None and active is None)
                   or (p is not None and active is not None and np.array_equal(p, active))
                   for p in self.possible)
        fresh = Controller(self.ctl.config, self.ctl.eeprom.path)  # what a reboot would load
        booted = fresh.active_table()
        fresh.close()
        assert (booted is None and active is None) or np.array_equal(booted, active)
        if active is not None:
            h = self.ctl.active_header
            assert h is not None and h.data_crc == table_crc(active)
            self.possible = [active]  # what survived is now the only truth


FirmwareMachine.TestCase.settings = _settings(max_examples=150, stateful_step_count=50,
                                             deadline=None)
test_firmware_state_machine = FirmwareMachine.TestCase
