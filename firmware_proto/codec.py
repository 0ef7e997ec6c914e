"""Encode and decode whole frames: header + message + CRC + COBS (PROTOCOL.md §2-3).

Pure functions; the only exception raised on bad input is
:class:`~grassd.firmware_proto.errors.FrameError`.

>>> from grassd.firmware_proto.messages import Hello
>>> wire = encode_frame(Frame(address=3, seq=0x1234, message=Hello()))
>>> wire.hex()
'0a0103013412cb99a6a000'
>>> decode_frame(wire[:-1])
Frame(address=3, seq=4660, message=Hello(), version=1)
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

from grassd.firmware_proto.errors import FrameError
from grassd.firmware_proto.framing import HEADER_SIZE, FrameReader, decode_body, encode_body
from grassd.firmware_proto.messages import PROTOCOL_VERSION, Message, unpack_payload

_HEADER = struct.Struct("<BBBH")


@dataclass(frozen=True)
class Frame:
    """One frame: who it is for / from, its sequence number and its message."""

    address: int
    seq: int
    message: Message
    version: int = PROTOCOL_VERSION


@dataclass(frozen=True)
class Header:
    """A frame header with its still-undecoded payload (for answering unknown types/versions)."""

    version: int
    address: int
    msg_type: int
    seq: int
    payload: bytes


def encode_body_of(frame: Frame) -> bytes:
    """Header + payload of ``frame`` (before CRC and COBS)."""
    try:
        head = _HEADER.pack(frame.version, frame.address, frame.message.TYPE, frame.seq)
    except struct.error as exc:
        raise FrameError(f"header field out of range: {exc}") from None
    return head + frame.message.pack()


def encode_frame(frame: Frame) -> bytes:
    """Wire bytes of ``frame``: COBS(header, payload, CRC-32) followed by the 0x00 delimiter."""
    return encode_body(encode_body_of(frame))


def parse_header(body: bytes) -> Header:
    """Split a CRC-checked body into header fields and payload (no version/type checks)."""
    if len(body) < HEADER_SIZE:
        raise FrameError(f"frame body of {len(body)} bytes is shorter than its header")
    version, address, msg_type, seq = _HEADER.unpack(body[:HEADER_SIZE])
    return Header(version, address, msg_type, seq, bytes(body[HEADER_SIZE:]))


def parse_body(body: bytes) -> Frame:
    """Decode a CRC-checked body (as :class:`~.framing.FrameReader` yields) into a Frame."""
    header = parse_header(body)
    if header.version != PROTOCOL_VERSION:
        raise FrameError(f"protocol version {header.version}, this side speaks "
                         f"{PROTOCOL_VERSION}")
    return Frame(header.address, header.seq, unpack_payload(header.msg_type, header.payload),
                 header.version)


def read_frames(reader: FrameReader, data: bytes) -> list[Frame]:
    """The frames that ``data`` completes in ``reader``, decoded; a CRC-checked body that
    does not decode (another protocol version, an unknown message) counts as bad in
    ``reader.stats`` and is dropped, like a body that fails its CRC."""
    frames = []
    for body in reader.feed(data):
        try:
            frames.append(parse_body(body))
        except FrameError:
            reader.stats.bad += 1
    return frames


def decode_frame(encoded: bytes) -> Frame:
    """Decode one COBS-encoded frame without its delimiter (checks COBS, CRC, header, payload)."""
    return parse_body(decode_body(encoded))
