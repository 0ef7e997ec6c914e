"""The protocol's messages as immutable values, with their payload encodings (PROTOCOL.md §3).

Each message class knows its type code and packs / unpacks its own payload (little-endian).
Unpacking bad bytes raises :class:`~grassd.firmware_proto.errors.FrameError` and nothing else.

>>> TableCommit(table_id=7, table_crc=0xCBF43926).pack().hex()
'070000002639f4cb'
>>> unpack_payload(MsgType.TABLE_COMMIT, bytes.fromhex('070000002639f4cb'))
TableCommit(table_id=7, table_crc=3421780262)
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, fields
from enum import IntEnum
from typing import ClassVar

from grassd.firmware_proto.errors import FrameError
from grassd.firmware_proto.framing import MAX_PAYLOAD

#: Protocol version carried in every frame header.
PROTOCOL_VERSION = 1
#: Entries in one length table (one per 8-bit level).
TABLE_ENTRIES = 256
#: Bytes of one length table (256 x u16 micrometres).
TABLE_BYTES = 2 * TABLE_ENTRIES
#: Largest TABLE_CHUNK data the frame format allows (payload minus table_id and offset).
MAX_CHUNK_DATA = MAX_PAYLOAD - 8
#: Largest POSITIONS count.
MAX_POSITIONS = 255
#: ``active_bank`` value meaning "no valid table".
NO_BANK = 0xFF
#: INFO ``features`` bit: the controller implements PATTERN / PATTERN_END (test patterns).
FEATURE_PATTERNS = 0x0001
#: INFO ``features`` bit: the controller implements STAGE_LEVEL / SHOW (the frame latch).
FEATURE_LATCH = 0x0002
#: Payload bytes of INFO before ``features`` existed (controllers without any feature bit).
INFO_V1_BASE_BYTES = 16
#: Most lengths one PATTERN frame carries (payload minus timeout_ds and first_pixel, 2 B each).
MAX_PATTERN_PIXELS = (MAX_PAYLOAD - 4) // 2
#: Most levels one STAGE_LEVEL frame carries (payload minus frame and first_pixel).
MAX_STAGE_PIXELS = MAX_PAYLOAD - 4

class MsgType(IntEnum):
    """Message type codes; requests have bit 7 clear, responses set."""

    HELLO = 0x01
    GET_STATUS = 0x02
    TABLE_BEGIN = 0x03
    TABLE_CHUNK = 0x04
    TABLE_COMMIT = 0x05
    SET_LEVEL = 0x06
    GET_POSITIONS = 0x07
    PATTERN = 0x08
    PATTERN_END = 0x09
    STAGE_LEVEL = 0x0A
    SHOW = 0x0B
    INFO = 0x81
    TABLE_STATUS = 0x82
    POSITIONS = 0x87
    ACK = 0x90
    NAK = 0x91


class NakCode(IntEnum):
    """NAK error codes (PROTOCOL.md §3)."""

    BAD_PAYLOAD = 1
    UNKNOWN_TYPE = 2
    UNSUPPORTED_VERSION = 3
    NO_TRANSFER = 4
    OUT_OF_RANGE = 5
    INCOMPLETE = 6
    CRC_MISMATCH = 7
    TOO_LARGE = 8
    BAD_KIND = 9
    VALUE_RANGE = 10
    NO_TABLE = 11
    BAD_PIXEL = 12
    STORAGE_FAILED = 13


class TableKind(IntEnum):
    """How a table transfer is laid out."""

    GLOBAL = 0  #: one table for every pixel
    PER_PIXEL = 1  #: one table per pixel, pixel p at byte offset 512 p


class StagingState(IntEnum):
    """``staging`` field of TABLE_STATUS."""

    IDLE = 0
    RECEIVING = 1


def nak_name(code: int) -> str:
    """Name of a NAK code, or ``"code N"`` for one this host does not know."""
    try:
        return NakCode(code).name
    except ValueError:
        return f"code {code}"


class Message:
    """Base of every message: a fixed struct part (``_FMT``) and maybe a trailing byte field."""

    TYPE: ClassVar[MsgType]
    _FMT: ClassVar[str] = "<"
    _TAIL: ClassVar[str | None] = None  # name of a trailing variable-length bytes field
    _TAIL_MIN: ClassVar[int] = 1
    _TAIL_MAX: ClassVar[int] = MAX_PAYLOAD
    _TAIL_STEP: ClassVar[int] = 1

    def _fixed_values(self) -> tuple:
        return tuple(getattr(self, f.name) for f in fields(self) if f.name != self._TAIL)

    def pack(self) -> bytes:
        """The payload bytes of this message."""
        try:
            head = struct.pack(self._FMT, *self._fixed_values())
        except struct.error as exc:
            raise FrameError(f"{type(self).__name__}: field out of range: {exc}") from None
        if self._TAIL is None:
            return head
        tail = bytes(getattr(self, self._TAIL))
        self._check_tail(len(tail))
        return head + tail

    @classmethod
    def _check_tail(cls, n: int) -> None:
        if not cls._TAIL_MIN <= n <= cls._TAIL_MAX or n % cls._TAIL_STEP:
            raise FrameError(f"{cls.__name__}: {cls._TAIL} of {n} bytes, expected "
                             f"{cls._TAIL_MIN}..{cls._TAIL_MAX} in steps of {cls._TAIL_STEP}")

    @classmethod
    def unpack(cls, payload: bytes) -> Message:
        """Decode a payload; raise :class:`FrameError` when its length or a field is invalid."""
        size = struct.calcsize(cls._FMT)
        if cls._TAIL is None and len(payload) != size:
            raise FrameError(f"{cls.__name__} payload is {len(payload)} bytes, expected {size}")
        if cls._TAIL is not None:
            if len(payload) < size:
                raise FrameError(f"{cls.__name__} payload is {len(payload)} bytes, "
                                 f"expected at least {size}")
            cls._check_tail(len(payload) - size)
        values = struct.unpack(cls._FMT, payload[:size])
        if cls._TAIL is not None:
            values = (*values, bytes(payload[size:]))
        return cls(*values)


@dataclass(frozen=True)
class Hello(Message):
    """Request: who are you? Answered by :class:`Info`."""

    TYPE: ClassVar[MsgType] = MsgType.HELLO


@dataclass(frozen=True)
class Info(Message):
    """Response to HELLO: versions, capacities and optional features of a controller.

    ``features`` (u16, a bit set, :data:`FEATURE_PATTERNS` = bit 0) came after the first v1
    controllers, whose INFO ends before it: :meth:`unpack` takes that 16-byte payload as
    ``features`` = 0, and ignores bytes after the fields it knows (later additions).
    """

    TYPE: ClassVar[MsgType] = MsgType.INFO
    _FMT: ClassVar[str] = "<BBBBIHHHHH"
    protocol_version: int
    fw_major: int
    fw_minor: int
    fw_patch: int
    uid: int
    n_pixels: int
    table_capacity: int  #: 256-entry tables one bank holds
    max_chunk: int  #: largest TABLE_CHUNK data accepted (bytes)
    max_length_um: int  #: longest grass the mechanism reaches (micrometres)
    features: int = 0  #: bit set of optional features (FEATURE_*); 0 from older controllers

    @property
    def firmware_version(self) -> str:
        """Firmware version as ``"major.minor.patch"``."""
        return f"{self.fw_major}.{self.fw_minor}.{self.fw_patch}"

    @property
    def supports_patterns(self) -> bool:
        """True when the controller takes PATTERN / PATTERN_END (raw lengths, watchdog)."""
        return bool(self.features & FEATURE_PATTERNS)

    @property
    def supports_latch(self) -> bool:
        """True when the controller takes STAGE_LEVEL / SHOW (levels shown on a broadcast)."""
        return bool(self.features & FEATURE_LATCH)

    def pack(self) -> bytes:
        """The payload: as received when decoded from the wire (an older controller's 16
        bytes, a newer one's later fields: a decoded frame re-encodes to the same bytes), else
        this version's form."""
        received = getattr(self, "_received", None)
        return super().pack() if received is None else received

    @classmethod
    def _decoded(cls, values: tuple, payload: bytes, **kw: int) -> Info:
        info = cls(*values, **kw)
        object.__setattr__(info, "_received", bytes(payload))  # not a field: not compared
        return info

    @classmethod
    def unpack(cls, payload: bytes) -> Message:
        """Decode INFO of 16 bytes (``features`` = 0) or of 18 and more (extra bytes ignored)."""
        size = struct.calcsize(cls._FMT)
        if len(payload) == INFO_V1_BASE_BYTES:
            return cls._decoded(struct.unpack(cls._FMT[:-1], payload), payload, features=0)
        if len(payload) < size:
            raise FrameError(f"Info payload is {len(payload)} bytes, expected "
                             f"{INFO_V1_BASE_BYTES} or at least {size}")
        return cls._decoded(struct.unpack(cls._FMT, payload[:size]), payload)


@dataclass(frozen=True)
class GetStatus(Message):
    """Request: which table is active? Answered by :class:`TableStatus`."""

    TYPE: ClassVar[MsgType] = MsgType.GET_STATUS


@dataclass(frozen=True)
class TableStatus(Message):
    """Response to GET_STATUS: the active table and the state of any open transfer."""

    TYPE: ClassVar[MsgType] = MsgType.TABLE_STATUS
    _FMT: ClassVar[str] = "<BBHIIIBI"
    active_bank: int  #: 0 or 1, or NO_BANK (0xFF) when no valid table exists
    kind: int  #: TableKind of the active table
    n_tables: int
    table_id: int
    table_crc: int  #: CRC-32/ISO-HDLC of the active table's bytes
    generation: int  #: commits so far
    staging: int  #: StagingState
    staged_bytes: int

    @property
    def has_table(self) -> bool:
        """True when a valid table is active."""
        return self.active_bank != NO_BANK


@dataclass(frozen=True)
class TableBegin(Message):
    """Request: open a transfer of ``total_bytes`` into the staging bank."""

    TYPE: ClassVar[MsgType] = MsgType.TABLE_BEGIN
    _FMT: ClassVar[str] = "<IBHII"
    table_id: int
    kind: int
    n_tables: int
    total_bytes: int
    table_crc: int


@dataclass(frozen=True)
class TableChunk(Message):
    """Request: write ``data`` at byte ``offset`` of the open transfer ``table_id``."""

    TYPE: ClassVar[MsgType] = MsgType.TABLE_CHUNK
    _FMT: ClassVar[str] = "<II"
    _TAIL: ClassVar[str] = "data"
    _TAIL_MAX: ClassVar[int] = MAX_CHUNK_DATA
    table_id: int
    offset: int
    data: bytes


@dataclass(frozen=True)
class TableCommit(Message):
    """Request: verify the staged table and make it active in one step."""

    TYPE: ClassVar[MsgType] = MsgType.TABLE_COMMIT
    _FMT: ClassVar[str] = "<II"
    table_id: int
    table_crc: int


@dataclass(frozen=True)
class SetLevel(Message):
    """Request: show ``levels[i]`` (8-bit) on pixel ``first_pixel + i``."""

    TYPE: ClassVar[MsgType] = MsgType.SET_LEVEL
    _FMT: ClassVar[str] = "<H"
    _TAIL: ClassVar[str] = "levels"
    _TAIL_MAX: ClassVar[int] = MAX_PAYLOAD - 2
    first_pixel: int
    levels: bytes


@dataclass(frozen=True)
class GetPositions(Message):
    """Request: encoder positions of ``count`` pixels from ``first_pixel``."""

    TYPE: ClassVar[MsgType] = MsgType.GET_POSITIONS
    _FMT: ClassVar[str] = "<HH"
    first_pixel: int
    count: int


@dataclass(frozen=True)
class Positions(Message):
    """Response: ``positions`` holds u16 pairs (position_um, target_um) per pixel, raw bytes."""

    TYPE: ClassVar[MsgType] = MsgType.POSITIONS
    _FMT: ClassVar[str] = "<H"
    _TAIL: ClassVar[str] = "positions"
    _TAIL_MIN: ClassVar[int] = 0
    _TAIL_MAX: ClassVar[int] = 4 * MAX_POSITIONS
    _TAIL_STEP: ClassVar[int] = 4
    first_pixel: int
    positions: bytes

    def pairs(self) -> list[tuple[int, int]]:
        """``(position_um, target_um)`` per pixel."""
        return list(struct.iter_unpack("<HH", self.positions))


@dataclass(frozen=True)
class Pattern(Message):
    """Request: drive pixel ``first_pixel + i`` to raw length ``lengths[i]`` (u16 LE bytes,
    micrometres), bypassing the active table; enter pattern mode, which ends by itself
    ``timeout_ds`` tenths of a second after the last PATTERN (PROTOCOL.md §3, test patterns)."""

    TYPE: ClassVar[MsgType] = MsgType.PATTERN
    _FMT: ClassVar[str] = "<HH"
    _TAIL: ClassVar[str] = "lengths"
    _TAIL_MIN: ClassVar[int] = 2
    _TAIL_MAX: ClassVar[int] = 2 * MAX_PATTERN_PIXELS
    _TAIL_STEP: ClassVar[int] = 2
    timeout_ds: int  #: watchdog, tenths of a second (1..65535)
    first_pixel: int
    lengths: bytes  #: u16 little-endian per pixel, micrometres

    def lengths_um(self) -> list[int]:
        """The lengths (micrometres), one per pixel from ``first_pixel``."""
        return [v for (v,) in struct.iter_unpack("<H", self.lengths)]


@dataclass(frozen=True)
class PatternEnd(Message):
    """Request: leave pattern mode; every pixel returns to normal display at once."""

    TYPE: ClassVar[MsgType] = MsgType.PATTERN_END


@dataclass(frozen=True)
class StageLevel(Message):
    """Request: stage ``levels[i]`` (8-bit) for pixel ``first_pixel + i`` as part of frame
    ``frame``; nothing moves until a :class:`Show` of that frame (PROTOCOL.md §3, the frame
    latch)."""

    TYPE: ClassVar[MsgType] = MsgType.STAGE_LEVEL
    _FMT: ClassVar[str] = "<HH"
    _TAIL: ClassVar[str] = "levels"
    _TAIL_MAX: ClassVar[int] = MAX_STAGE_PIXELS
    frame: int  #: the host's frame number (u16, wraps)
    first_pixel: int
    levels: bytes


@dataclass(frozen=True)
class Show(Message):
    """Request, usually broadcast (address 0, never answered): every controller that staged
    frame ``frame`` shows it now; to one controller's address it is answered ACK."""

    TYPE: ClassVar[MsgType] = MsgType.SHOW
    _FMT: ClassVar[str] = "<H"
    frame: int


@dataclass(frozen=True)
class Ack(Message):
    """Response: the request of type ``request_type`` was carried out."""

    TYPE: ClassVar[MsgType] = MsgType.ACK
    _FMT: ClassVar[str] = "<B"
    request_type: int


@dataclass(frozen=True)
class Nak(Message):
    """Response: the request was refused with NAK ``error`` (a NakCode) and ``detail``."""

    TYPE: ClassVar[MsgType] = MsgType.NAK
    _FMT: ClassVar[str] = "<BBI"
    request_type: int
    error: int
    detail: int


#: Message class of every type code.
MESSAGE_CLASSES: dict[int, type[Message]] = {
    cls.TYPE: cls
    for cls in (Hello, Info, GetStatus, TableStatus, TableBegin, TableChunk, TableCommit,
                SetLevel, GetPositions, Pattern, PatternEnd, StageLevel, Show, Positions, Ack,
                Nak)
}

#: Response types a request may be answered with (besides NAK).
RESPONSE_TYPES: dict[int, MsgType] = {
    MsgType.HELLO: MsgType.INFO,
    MsgType.GET_STATUS: MsgType.TABLE_STATUS,
    MsgType.TABLE_BEGIN: MsgType.ACK,
    MsgType.TABLE_CHUNK: MsgType.ACK,
    MsgType.TABLE_COMMIT: MsgType.ACK,
    MsgType.SET_LEVEL: MsgType.ACK,
    MsgType.GET_POSITIONS: MsgType.POSITIONS,
    MsgType.PATTERN: MsgType.ACK,
    MsgType.PATTERN_END: MsgType.ACK,
    MsgType.STAGE_LEVEL: MsgType.ACK,
    MsgType.SHOW: MsgType.ACK,
}


def unpack_payload(msg_type: int, payload: bytes) -> Message:
    """Decode the payload of a message of type ``msg_type``; :class:`FrameError` if invalid."""
    cls = MESSAGE_CLASSES.get(msg_type)
    if cls is None:
        raise FrameError(f"unknown message type {msg_type:#04x}")
    return cls.unpack(payload)
