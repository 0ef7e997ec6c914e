"""The controller state machine, as the firmware implements it (PROTOCOL.md §3-4).

:class:`Controller` takes CRC-checked frame bodies addressed to the bus and returns the bytes
to send back (or nothing). It owns a :class:`~.eeprom.BankStore` on a file-backed
:class:`~.eeprom.Eeprom`, a RAM copy of the active table, an open transfer, a one-entry reply
cache for retransmissions, and the pixels' motors, which move towards their targets at a
limited speed and are read through encoders of finite resolution.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from grassd.firmware_proto.codec import Frame, encode_frame, parse_header
from grassd.firmware_proto.crc import crc32_iso_hdlc
from grassd.firmware_proto.errors import FrameError, SimulatorError
from grassd.firmware_proto.framing import BROADCAST_ADDRESS, MAX_ADDRESS, MIN_ADDRESS
from grassd.firmware_proto.messages import (
    FEATURE_LATCH,
    FEATURE_PATTERNS,
    INFO_V1_BASE_BYTES,
    MAX_CHUNK_DATA,
    MAX_POSITIONS,
    NO_BANK,
    PROTOCOL_VERSION,
    TABLE_BYTES,
    Ack,
    GetPositions,
    GetStatus,
    Hello,
    Info,
    Message,
    MsgType,
    Nak,
    NakCode,
    Pattern,
    PatternEnd,
    Positions,
    SetLevel,
    Show,
    StageLevel,
    StagingState,
    TableBegin,
    TableChunk,
    TableCommit,
    TableKind,
    TableStatus,
    unpack_payload,
)
from grassd.firmware_proto.tables import table_from_bytes
from grassd.rigs.eeprom import BankHeader, BankStore, Eeprom, PowerLoss


@dataclass(frozen=True)
class ControllerConfig:
    """Fixed properties of one (simulated) controller."""

    address: int = 1
    n_pixels: int = 16
    uid: int = 0x6A5D0001
    firmware_version: tuple[int, int, int] = (1, 0, 0)
    table_capacity: int | None = None  #: tables per bank; default n_pixels (per-pixel tables fit)
    max_chunk: int = 256  #: bytes of TABLE_CHUNK data accepted
    max_length_um: int = 20_000  #: 20 mm, the paper's longest green grass
    speed_um_s: float = 20_000.0  #: motor speed limit, micrometres per second
    encoder_um: float = 12.5  #: encoder resolution, micrometres per count
    boot_s: float = 0.0  #: after power-on the controller ignores the bus this long (seconds)
    #: implements test patterns (PATTERN / PATTERN_END, INFO features bit 0); False answers
    #: as a controller from before them: 16-byte INFO, NAK UNKNOWN_TYPE to 0x08 / 0x09
    patterns: bool = True
    #: implements the frame latch (STAGE_LEVEL / SHOW, INFO features bit 1); False answers as
    #: a controller from before it: NAK UNKNOWN_TYPE to 0x0A / 0x0B, a broadcast SHOW ignored
    #: (a controller without ``patterns``, from before INFO's features, has no latch either)
    latch: bool = True

    def __post_init__(self) -> None:
        if not MIN_ADDRESS <= self.address <= MAX_ADDRESS:
            raise SimulatorError(f"controller address must be {MIN_ADDRESS}..{MAX_ADDRESS}, "
                                 f"got {self.address}")
        if not 1 <= self.n_pixels <= 0xFFFF:
            raise SimulatorError(f"n_pixels must be 1..65535, got {self.n_pixels}")
        if not 1 <= self.max_chunk <= MAX_CHUNK_DATA:
            raise SimulatorError(f"max_chunk must be 1..{MAX_CHUNK_DATA}, got {self.max_chunk}")

    @property
    def has_latch(self) -> bool:
        """True when it implements STAGE_LEVEL / SHOW (``latch`` on a controller with features)."""
        return self.latch and self.patterns

    @property
    def capacity(self) -> int:
        """Tables per bank."""
        return self.table_capacity if self.table_capacity is not None else self.n_pixels


#: Simulated controller ``a`` reports uid ``SIM_UID_BASE + a`` (the C firmware's posix port
#: uses the same numbering).
SIM_UID_BASE = 0x6A5D0000


def simulated_config(address: int, **fields: object) -> ControllerConfig:
    """The configuration of simulated controller ``address`` (model, posix or QEMU): uid
    ``SIM_UID_BASE + address``, other fields as given, else ControllerConfig's defaults."""
    return ControllerConfig(address=address, uid=SIM_UID_BASE + address, **fields)


def bus_pixels(what: str, addresses: Sequence[int],
               n_pixels: int | Sequence[int]) -> list[int]:
    """Check the controller ``addresses`` of one simulated bus (``what``, e.g. "a QEMU bus":
    at least one, all distinct) and return the pixel count of each: ``n_pixels`` is one value
    for all or one per address. Raises :class:`SimulatorError`."""
    if not addresses:
        raise SimulatorError(f"{what} needs at least one controller")
    if len(set(addresses)) != len(addresses):
        raise SimulatorError(f"two controllers on one bus share an address: {list(addresses)}")
    pixels = [n_pixels] * len(addresses) if isinstance(n_pixels, int) else list(n_pixels)
    if len(pixels) != len(addresses):
        raise SimulatorError(f"{len(pixels)} pixel counts for {len(addresses)} controllers: "
                             "give one for all or one per address")
    return pixels


@dataclass(frozen=True)
class _InfoBeforeFeatures(Info):
    """INFO as controllers from before the ``features`` field send it (16 bytes)."""

    def pack(self) -> bytes:
        return super().pack()[:INFO_V1_BASE_BYTES]


@dataclass
class _Transfer:
    begin: TableBegin
    bank: int
    received: bytearray = field(default_factory=bytearray)  # one flag per byte

    def first_missing(self) -> int:
        idx = self.received.find(0)
        return len(self.received) if idx < 0 else idx


class Controller:
    """One controller: protocol state machine, two-bank store, motors. Thread-safe.

    ``clock`` gives seconds (monotonic); it drives motion, the boot delay and the test
    pattern's watchdog (which ends pattern mode at its deadline whenever the controller is
    next looked at: a frame, or :meth:`positions_um`).
    """

    def __init__(self, config: ControllerConfig, eeprom_path: str | Path,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.config = config
        self.clock = clock
        self.eeprom = Eeprom(eeprom_path, BankStore.required_size(config.capacity))
        self.store = BankStore(self.eeprom, config.capacity)
        self._lock = threading.RLock()
        n = config.n_pixels
        self._pos = np.zeros(n)  # physical positions survive a reboot
        self._target = np.zeros(n)
        self._normal = np.zeros(n)  # targets of normal display (shown when no pattern is)
        self._pattern_until: float | None = None  # clock time the pattern's watchdog ends it
        self._staged = np.zeros(n, dtype=np.uint8)  # the frame latch: levels staged
        self._staged_mask = np.zeros(n, dtype=bool)  # ... and which pixels a STAGE named
        self._stage_frame: int | None = None  # the frame number they belong to
        self._t = clock()
        self.boots = 0
        self.boot()

    # --- power ---------------------------------------------------------------------------
    def boot(self) -> None:
        """Start the firmware: select the active bank, load its table, forget all RAM state."""
        with self._lock:
            self._advance()
            self.active_bank, self.active_header = self.store.select_active()
            self.table: np.ndarray | None = None
            if self.active_header is not None:
                h = self.active_header
                data = self.store.read_data(self.active_bank, h.n_tables * TABLE_BYTES)
                self.table = table_from_bytes(data, h.n_tables, TableKind(h.kind))
            self.transfer: _Transfer | None = None
            self._last: tuple[int, int, bytes] | None = None  # (seq, body crc, reply)
            self._target = self._pos.copy()  # motors stop where they are
            self._normal = self._target.copy()
            self._pattern_until = None  # pattern mode lives in RAM only
            self._staged_mask[:] = False  # so does the latch
            self._stage_frame = None
            self._ready_at = self.clock() + self.config.boot_s
            self.boots += 1

    def power_cycle(self) -> None:
        """Cut power and restart: only what reached the EEPROM file survives."""
        with self._lock:
            self.eeprom.reload()
            self.boot()

    def close(self) -> None:
        """Release the EEPROM file."""
        self.eeprom.close()

    # --- ground truth for tests and the simulator ----------------------------------------
    def active_table(self) -> np.ndarray | None:
        """Copy of the table the controller uses now (um), or None."""
        with self._lock:
            return None if self.table is None else self.table.copy()

    @property
    def in_pattern(self) -> bool:
        """True while a test pattern is shown (after advancing the watchdog to now)."""
        with self._lock:
            self._advance()
            return self._pattern_until is not None

    def targets_um(self) -> np.ndarray:
        """Every pixel's target (um) the motors drive towards now."""
        with self._lock:
            self._advance()
            return np.round(self._target)

    def positions_um(self) -> np.ndarray:
        """Encoder readings of every pixel (um), after advancing the motion to now."""
        with self._lock:
            self._advance()
            return self._encoder()

    # --- bus ------------------------------------------------------------------------------
    def handle(self, body: bytes) -> bytes | None:
        """Process one CRC-checked frame body; return the wire bytes of the answer, or None.

        Frames for other addresses, responses, and frames arriving while booting are ignored.
        A broadcast (address 0) SHOW is carried out and never answered; the reply cache is
        left as it was. A simulated power loss inside an EEPROM write reboots the controller
        (no answer).
        """
        try:
            header = parse_header(body)
        except FrameError:
            return None
        cfg = self.config
        if header.address == BROADCAST_ADDRESS and not header.msg_type & 0x80:
            self._broadcast(header.version, header.msg_type, header.payload)
            return None
        if header.address != cfg.address or header.msg_type & 0x80:
            return None
        with self._lock:
            if self.clock() < self._ready_at:
                return None
            self._advance()  # a pattern whose watchdog ran out ends before this frame
            key = (header.seq, crc32_iso_hdlc(body))
            if self._last is not None and self._last[:2] == key:
                return self._last[2]
            try:
                reply = self._dispatch(header.version, header.msg_type, header.payload)
            except PowerLoss:
                self.power_cycle()
                return None
            except OSError:
                reply = Nak(header.msg_type, NakCode.STORAGE_FAILED, 0)
            wire = encode_frame(Frame(cfg.address, header.seq, reply))
            self._last = (*key, wire)
            return wire

    def _dispatch(self, version: int, msg_type: int, payload: bytes) -> Message:
        if version != PROTOCOL_VERSION:
            return Nak(msg_type, NakCode.UNSUPPORTED_VERSION, PROTOCOL_VERSION)
        try:
            msg = unpack_payload(msg_type, payload)
        except FrameError:
            known = msg_type in MsgType.__members__.values() and self._knows(msg_type)
            code = NakCode.BAD_PAYLOAD if known else NakCode.UNKNOWN_TYPE
            return Nak(msg_type, code, len(payload))
        if not self._knows(msg_type):
            return Nak(msg_type, NakCode.UNKNOWN_TYPE, len(payload))
        handler = {
            Hello: self._hello, GetStatus: self._status, TableBegin: self._begin,
            TableChunk: self._chunk, TableCommit: self._commit, SetLevel: self._set_level,
            GetPositions: self._get_positions, Pattern: self._pattern,
            PatternEnd: self._pattern_end, StageLevel: self._stage_level, Show: self._show,
        }[type(msg)]
        return handler(msg)

    def _knows(self, msg_type: int) -> bool:
        if msg_type in (MsgType.PATTERN, MsgType.PATTERN_END):
            return self.config.patterns
        if msg_type in (MsgType.STAGE_LEVEL, MsgType.SHOW):
            return self.config.has_latch
        return True

    def _broadcast(self, version: int, msg_type: int, payload: bytes) -> None:
        """A frame to every controller: a SHOW this controller knows is carried out; anything
        else (another type, version or a bad payload) is ignored. Never answered."""
        if (version != PROTOCOL_VERSION or msg_type != MsgType.SHOW
                or not self._knows(msg_type)):
            return
        try:
            msg = unpack_payload(msg_type, payload)
        except FrameError:
            return
        with self._lock:
            if self.clock() < self._ready_at:
                return
            self._advance()
            self._show(msg)

    # --- handlers -------------------------------------------------------------------------
    def _hello(self, _: Hello) -> Message:
        c = self.config
        if not c.patterns:
            return _InfoBeforeFeatures(PROTOCOL_VERSION, *c.firmware_version, c.uid, c.n_pixels,
                                       c.capacity, c.max_chunk, c.max_length_um)
        features = FEATURE_PATTERNS | (FEATURE_LATCH if c.has_latch else 0)
        return Info(PROTOCOL_VERSION, *c.firmware_version, c.uid, c.n_pixels, c.capacity,
                    c.max_chunk, c.max_length_um, features)

    def _status(self, _: GetStatus) -> Message:
        h, t = self.active_header, self.transfer
        staging = (StagingState.RECEIVING, t.received.count(1)) if t else (StagingState.IDLE, 0)
        if h is None:
            return TableStatus(NO_BANK, 0, 0, 0, 0, 0, *staging)
        return TableStatus(self.active_bank, h.kind, h.n_tables, h.table_id, h.data_crc,
                           h.generation, *staging)

    def _begin(self, m: TableBegin) -> Message:
        c = self.config
        if m.kind == TableKind.GLOBAL:
            ok = m.n_tables == 1
        elif m.kind == TableKind.PER_PIXEL:
            ok = m.n_tables == c.n_pixels
        else:
            ok = False
        if not ok or m.total_bytes != m.n_tables * TABLE_BYTES:
            return Nak(m.TYPE, NakCode.BAD_KIND, c.n_pixels)
        if m.n_tables > c.capacity:
            return Nak(m.TYPE, NakCode.TOO_LARGE, c.capacity)
        if self.transfer is not None and self.transfer.begin == m:
            return Ack(m.TYPE)  # retransmitted BEGIN: keep what has arrived
        bank = 0 if self.active_bank in (None, 1) else 1
        self.transfer = None
        self.store.invalidate(bank)
        self.transfer = _Transfer(m, bank, bytearray(m.total_bytes))
        return Ack(m.TYPE)

    def _chunk(self, m: TableChunk) -> Message:
        t = self.transfer
        if t is None or t.begin.table_id != m.table_id:
            return Nak(m.TYPE, NakCode.NO_TRANSFER, 0)
        if len(m.data) > self.config.max_chunk:
            return Nak(m.TYPE, NakCode.TOO_LARGE, self.config.max_chunk)
        end = m.offset + len(m.data)
        if end > t.begin.total_bytes:
            return Nak(m.TYPE, NakCode.OUT_OF_RANGE, t.begin.total_bytes)
        self.store.write_data(t.bank, m.offset, m.data)
        t.received[m.offset:end] = b"\x01" * len(m.data)
        return Ack(m.TYPE)

    def _commit(self, m: TableCommit) -> Message:
        t, h = self.transfer, self.active_header
        if t is None:
            if h is not None and (h.table_id, h.data_crc) == (m.table_id, m.table_crc):
                return Ack(m.TYPE)  # committed before; only the ACK was lost
            return Nak(m.TYPE, NakCode.NO_TRANSFER, 0)
        b = t.begin
        if (b.table_id, b.table_crc) != (m.table_id, m.table_crc):
            return Nak(m.TYPE, NakCode.NO_TRANSFER, 0)
        missing = t.first_missing()
        if missing < b.total_bytes:
            return Nak(m.TYPE, NakCode.INCOMPLETE, missing)
        data = self.store.read_data(t.bank, b.total_bytes)  # verify what the memory holds
        crc = crc32_iso_hdlc(data)
        if crc != b.table_crc:
            self.transfer = None
            return Nak(m.TYPE, NakCode.CRC_MISMATCH, crc)
        table = table_from_bytes(data, b.n_tables, TableKind(b.kind))
        over = np.flatnonzero(table.reshape(-1) > self.config.max_length_um)
        if over.size:
            self.transfer = None
            return Nak(m.TYPE, NakCode.VALUE_RANGE, int(over[0]))
        generation = (h.generation + 1) if h is not None else 1
        header = BankHeader(generation, b.table_id, b.kind, b.n_tables, b.table_crc)
        self.store.write_header(t.bank, header)  # the one-step switch
        self.active_bank, self.active_header, self.table = t.bank, header, table
        self.transfer = None
        return Ack(m.TYPE)

    def _set_level(self, m: SetLevel) -> Message:
        n = self.config.n_pixels
        if m.first_pixel + len(m.levels) > n:
            return Nak(m.TYPE, NakCode.BAD_PIXEL, n)
        if self.table is None:
            return Nak(m.TYPE, NakCode.NO_TABLE, 0)
        self._advance()
        levels = np.frombuffer(m.levels, dtype=np.uint8)
        self._apply_levels(np.arange(m.first_pixel, m.first_pixel + levels.size), levels)
        return Ack(m.TYPE)

    def _apply_levels(self, pixels: np.ndarray, levels: np.ndarray) -> None:
        """Normal display of ``pixels`` becomes ``table[levels]``, the table active now."""
        if self.table.ndim == 1:
            self._normal[pixels] = self.table[levels]
        else:
            self._normal[pixels] = self.table[pixels, levels]
        if self._pattern_until is None:  # a pattern holds every pixel until it ends
            self._target[pixels] = self._normal[pixels]

    def _stage_level(self, m: StageLevel) -> Message:
        n = self.config.n_pixels
        if m.first_pixel + len(m.levels) > n:
            return Nak(m.TYPE, NakCode.BAD_PIXEL, n)
        if self.table is None:
            return Nak(m.TYPE, NakCode.NO_TABLE, 0)
        if m.frame != self._stage_frame:  # a new frame: what another one staged is dropped
            self._staged_mask[:] = False
            self._stage_frame = m.frame
        sl = slice(m.first_pixel, m.first_pixel + len(m.levels))
        self._staged[sl] = np.frombuffer(m.levels, dtype=np.uint8)
        self._staged_mask[sl] = True
        return Ack(m.TYPE)

    def _show(self, m: Show) -> Message:
        """The staged pixels of frame ``m.frame`` take their levels through the table active
        now; a SHOW of another frame drops what is staged. Staging is empty afterwards."""
        if m.frame == self._stage_frame and self._staged_mask.any() and self.table is not None:
            pixels = np.flatnonzero(self._staged_mask)
            self._apply_levels(pixels, self._staged[pixels])
        self._staged_mask[:] = False
        self._stage_frame = None
        return Ack(m.TYPE)

    def _pattern(self, m: Pattern) -> Message:
        n = self.config.n_pixels
        if m.timeout_ds == 0:
            return Nak(m.TYPE, NakCode.BAD_PAYLOAD, 0)
        lengths = np.asarray(m.lengths_um())
        if m.first_pixel + lengths.size > n:
            return Nak(m.TYPE, NakCode.BAD_PIXEL, n)
        over = np.flatnonzero(lengths > self.config.max_length_um)
        if over.size:
            return Nak(m.TYPE, NakCode.VALUE_RANGE, int(over[0]))
        self._advance()
        self._target[m.first_pixel:m.first_pixel + lengths.size] = lengths
        self._pattern_until = self.clock() + m.timeout_ds / 10  # (re-)armed
        return Ack(m.TYPE)

    def _pattern_end(self, m: PatternEnd) -> Message:
        self._advance()
        self._end_pattern()
        return Ack(m.TYPE)

    def _end_pattern(self) -> None:
        """Every pixel back to normal display (a no-op outside pattern mode)."""
        if self._pattern_until is not None:
            self._target = self._normal.copy()
            self._pattern_until = None

    def _get_positions(self, m: GetPositions) -> Message:
        n = self.config.n_pixels
        if not 1 <= m.count <= MAX_POSITIONS:
            return Nak(m.TYPE, NakCode.BAD_PAYLOAD, m.count)
        if m.first_pixel + m.count > n:
            return Nak(m.TYPE, NakCode.BAD_PIXEL, n)
        self._advance()
        sl = slice(m.first_pixel, m.first_pixel + m.count)
        pairs = np.stack([self._encoder()[sl], np.round(self._target[sl])], axis=1)
        return Positions(m.first_pixel, pairs.astype("<u2").tobytes())

    # --- motion ---------------------------------------------------------------------------
    def _advance(self) -> None:
        """Move every motor towards its target for the time elapsed, at most speed_um_s;
        a pattern whose watchdog ran out ends at its deadline, on the way."""
        now = self.clock()
        if self._pattern_until is not None and now >= self._pattern_until:
            self._move(self._pattern_until)
            self._end_pattern()
        self._move(now)

    def _move(self, now: float) -> None:
        step = self.config.speed_um_s * max(0.0, now - self._t)
        self._t = max(self._t, now)
        self._pos += np.clip(self._target - self._pos, -step, step)

    def _encoder(self) -> np.ndarray:
        res = self.config.encoder_um
        return np.round(np.round(self._pos / res) * res)

