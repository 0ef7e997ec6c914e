"""Framing of a byte stream: COBS-stuffed frames delimited by 0x00, each with a CRC-32 trailer.

Pure and transport-free, in the style of ``serial.threaded.FramedPacket``: feed received bytes
to a :class:`FrameReader` and it hands back complete frame bodies, skipping garbage. See
PROTOCOL.md section 2.

>>> wire = encode_body(b"\\x01\\x05\\x01\\x00\\x00")
>>> FrameReader().feed(b"garbage\\x00" + wire)
[b'\\x01\\x05\\x01\\x00\\x00']
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

from cobs import cobs

from grassd.firmware_proto.crc import crc32_iso_hdlc
from grassd.firmware_proto.errors import FrameError

#: Frame delimiter on the wire.
DELIMITER = b"\x00"
#: Header: version, address, type, seq.
HEADER_SIZE = 5
#: Addresses a controller may have, the header's address byte (0 and 248..255 are reserved).
MIN_ADDRESS, MAX_ADDRESS = 1, 247
#: The broadcast address: every controller on the bus takes the frame and none answers (only
#: SHOW may be broadcast; PROTOCOL.md section 2).
BROADCAST_ADDRESS = 0
#: CRC-32 trailer size.
CRC_SIZE = 4
#: Largest payload a frame may carry (bytes).
MAX_PAYLOAD = 1024
#: Largest body (header + payload, without CRC) in bytes.
MAX_BODY = HEADER_SIZE + MAX_PAYLOAD
#: Largest COBS-encoded frame without its delimiter: body + CRC + one overhead byte per 254.
MAX_ENCODED = MAX_BODY + CRC_SIZE + (MAX_BODY + CRC_SIZE + 253) // 254
_MIN_FRAME = HEADER_SIZE + CRC_SIZE


def encode_body(body: bytes) -> bytes:
    """Append the CRC-32/ISO-HDLC to ``body``, COBS-encode it and add the 0x00 delimiter."""
    if len(body) > MAX_BODY:
        raise FrameError(f"frame body of {len(body)} bytes exceeds the {MAX_BODY}-byte limit")
    return cobs.encode(body + struct.pack("<I", crc32_iso_hdlc(body))) + DELIMITER


def decode_body(encoded: bytes) -> bytes:
    """Undo :func:`encode_body` for one frame (without delimiter): check COBS, size and CRC.

    Returns the body (header + payload). Raises :class:`FrameError` for anything invalid.
    """
    if len(encoded) > MAX_ENCODED:
        raise FrameError(f"frame of {len(encoded)} bytes exceeds the {MAX_ENCODED}-byte limit")
    try:
        raw = cobs.decode(encoded)
    except cobs.DecodeError as exc:
        raise FrameError(f"bad COBS encoding: {exc}") from None
    if len(raw) < _MIN_FRAME:
        raise FrameError(f"frame of {len(raw)} bytes is shorter than the {_MIN_FRAME}-byte minimum")
    body, (crc,) = raw[:-CRC_SIZE], struct.unpack("<I", raw[-CRC_SIZE:])
    if crc32_iso_hdlc(body) != crc:
        raise FrameError(f"CRC mismatch: frame says {crc:#010x}, data gives "
                         f"{crc32_iso_hdlc(body):#010x}")
    return body


@dataclass
class FramingStats:
    """Counters of a :class:`FrameReader` (for diagnostics and tests)."""

    frames: int = 0  #: frames handed out with a valid CRC
    bad: int = 0  #: non-empty frames dropped (COBS, length or CRC failure)
    oversized: int = 0  #: runs of bytes longer than a frame, discarded up to the next delimiter


class FrameReader:
    """Reassemble frames from a byte stream: feed bytes, get complete, CRC-checked bodies.

    Garbage is skipped: a damaged frame is dropped and reading resumes at the next delimiter;
    a run of more than :data:`MAX_ENCODED` bytes without a delimiter is discarded as it comes,
    so memory stays bounded whatever the line delivers.
    """

    def __init__(self) -> None:
        self._buffer = bytearray()
        self._discarding = False
        self.stats = FramingStats()

    def reset(self) -> None:
        """Forget any partial frame (after a reconnect or a reboot)."""
        self._buffer.clear()
        self._discarding = False

    def feed(self, data: bytes) -> list[bytes]:
        """Consume received bytes; return the bodies of every frame they complete, in order."""
        bodies: list[bytes] = []
        start = 0
        while True:
            end = data.find(0, start)
            piece = data[start:] if end < 0 else data[start:end]
            if not self._discarding:
                self._buffer += piece
                if len(self._buffer) > MAX_ENCODED:
                    self.stats.oversized += 1
                    self._buffer.clear()
                    self._discarding = True
            if end < 0:
                return bodies
            if not self._discarding and self._buffer:
                try:
                    bodies.append(decode_body(bytes(self._buffer)))
                    self.stats.frames += 1
                except FrameError:
                    self.stats.bad += 1
            self._buffer.clear()
            self._discarding = False
            start = end + 1
