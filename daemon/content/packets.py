"""The two live wire formats, decoded strictly: an E1.31 (sACN) data packet and an Art-Net
ArtDmx packet, each into a :class:`DmxPacket`.

Every field a receiver relies on is checked (identifiers, vectors, the three PDU lengths of
E1.31 against the datagram's size, DMP address and data types, the slot count; Art-Net's
opcode, protocol version and even length). A datagram that fails is :class:`Malformed`; a
well-formed one that is not for us (E1.31 synchronisation or discovery, a start code other
than 0 such as per-address priority, preview data; ArtPoll, ArtSync and other opcodes) is
:class:`NotDmx`. Both are counted by the receiver and dropped, never raised further.

E1.31-2018 data packet (offsets in bytes): root layer 0-37 (preamble 0x0010, postamble 0,
``ASC-E1.17``, flags+length, vector 4, CID), framing layer 38-114 (flags+length, vector 2,
source name, priority 0..200, sync address, sequence, options, universe 1..63999), DMP
layer 115-125 (flags+length, vector 2, 0xa1, first address 0, increment 1, count, start
code), then up to 512 slots. Art-Net 4 ArtDmx: ``Art-Net\\0``, opcode 0x5000 (little
endian), version >= 14, sequence, physical, SubUni, Net, length (2..512, even), data.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

from grassd.daemon.core.errors import DaemonError

#: the largest E1.31 data packet (126 header bytes + 512 slots) and ArtDmx (18 + 512)
E131_MAX = 638
ARTDMX_MAX = 530
E131_HEADER = 126
ARTDMX_HEADER = 18
_ACN_ID = b"ASC-E1.17\x00\x00\x00"
_ARTNET_ID = b"Art-Net\x00"
_OP_DMX = 0x5000
_VECTOR_ROOT_DATA = 4
_VECTOR_ROOT_EXTENDED = 8  # synchronisation and universe discovery
_VECTOR_FRAMING_DATA = 2
_OPT_PREVIEW = 0x80
_OPT_TERMINATED = 0x40
_E131 = struct.Struct("!HH12sHI16sHI64sBHBBHHBBHHH")
_ARTDMX = struct.Struct("<8sH")


class PacketError(DaemonError):
    """A datagram a receiver does not use (base of the two kinds below)."""


class Malformed(PacketError):
    """A datagram that claims to be E1.31 / Art-Net but breaks the format (a field out of
    range, lengths that disagree, too short or too long): dropped and counted."""


class NotDmx(PacketError):
    """A well-formed datagram that carries no levels for a display (E1.31 sync or discovery,
    a non-zero start code, preview data; Art-Net opcodes other than ArtDmx)."""


@dataclass(frozen=True, eq=False)
class DmxPacket:
    """One universe's levels from one sender. ``source``: the sender's identity (E1.31: its
    CID, 16 bytes; Art-Net: "ip:port"); ``universe``: E1.31 universe (1..63999) or Art-Net
    15-bit port-address; ``priority`` 0..200 (Art-Net has none: 100, E1.31's default);
    ``sequence`` 0..255, or -1 where the sender does not number its packets (Art-Net 0);
    ``terminated``: E1.31's stream-terminated option; ``data``: the slots after the start
    code (1..512 bytes)."""

    source: bytes | str
    universe: int
    priority: int
    sequence: int
    terminated: bool
    data: bytes
    name: str = ""


def decode_e131(buf: bytes | memoryview) -> DmxPacket:
    """The E1.31 data packet in ``buf``; raises :class:`Malformed` or :class:`NotDmx`."""
    n = len(buf)
    if n > E131_MAX:
        raise Malformed(f"{n} bytes: longer than an E1.31 data packet ({E131_MAX})")
    if n < 38:
        raise Malformed(f"{n} bytes: shorter than an E1.31 root layer")
    if bytes(buf[0:16]) != b"\x00\x10\x00\x00" + _ACN_ID:
        raise Malformed("not an ACN root layer (preamble, postamble or identifier)")
    root_flags = int.from_bytes(buf[16:18], "big")
    root_vector = int.from_bytes(buf[18:22], "big")
    if root_flags >> 12 != 0x7 or (root_flags & 0x0FFF) != n - 16:
        raise Malformed("root layer length disagrees with the datagram")
    if root_vector == _VECTOR_ROOT_EXTENDED:
        raise NotDmx("E1.31 synchronisation or universe discovery")
    if root_vector != _VECTOR_ROOT_DATA:
        raise Malformed(f"unknown root vector {root_vector}")
    if n < E131_HEADER + 1:
        raise Malformed(f"{n} bytes: shorter than an E1.31 data packet with one slot")
    (_, _, _, _, _, cid, fr_flags, fr_vector, name, priority, _sync, sequence, options,
     universe, dmp_flags, dmp_vector, types, first, incr, count) = _E131.unpack_from(buf, 0)
    if fr_flags >> 12 != 0x7 or (fr_flags & 0x0FFF) != n - 38:
        raise Malformed("framing layer length disagrees with the datagram")
    if fr_vector != _VECTOR_FRAMING_DATA:
        raise Malformed(f"unknown framing vector {fr_vector}")
    if priority > 200:
        raise Malformed(f"priority {priority} above 200")
    if not 1 <= universe <= 63999:
        raise Malformed(f"universe {universe} outside 1..63999")
    if dmp_flags >> 12 != 0x7 or (dmp_flags & 0x0FFF) != n - 115:
        raise Malformed("DMP layer length disagrees with the datagram")
    if dmp_vector != 2 or types != 0xA1 or first != 0 or incr != 1:
        raise Malformed("DMP layer is not E1.31's set-property message")
    if count != n - 125 or not 1 <= count <= 513:
        raise Malformed(f"property count {count} disagrees with the datagram")
    if options & _OPT_PREVIEW:
        raise NotDmx("preview data (for visualisers only)")
    terminated = bool(options & _OPT_TERMINATED)
    if buf[125] != 0 and not terminated:
        raise NotDmx(f"start code {buf[125]:#04x} (not levels)")
    text = bytes(name).split(b"\x00", 1)[0].decode("utf-8", "replace")
    return DmxPacket(bytes(cid), universe, priority, sequence, terminated,
                     bytes(buf[126:n]), text[:64])


def decode_artdmx(buf: bytes | memoryview, sender: str) -> DmxPacket:
    """The ArtDmx packet in ``buf`` from ``sender`` ("ip:port"); raises :class:`Malformed`
    or :class:`NotDmx`."""
    n = len(buf)
    if n > ARTDMX_MAX:
        raise Malformed(f"{n} bytes: longer than an ArtDmx packet ({ARTDMX_MAX})")
    if n < 10 or bytes(buf[0:8]) != _ARTNET_ID:
        raise Malformed("not an Art-Net packet (identifier)")
    opcode = _ARTDMX.unpack_from(buf, 0)[1]
    if opcode != _OP_DMX:
        raise NotDmx(f"Art-Net opcode {opcode:#06x} (not ArtDmx)")
    if n < ARTDMX_HEADER + 2:
        raise Malformed(f"{n} bytes: shorter than an ArtDmx packet with two slots")
    version = (buf[10] << 8) | buf[11]
    if version < 14:
        raise Malformed(f"Art-Net protocol version {version} below 14")
    if buf[15] & 0x80:
        raise Malformed("Net above 127")
    length = (buf[16] << 8) | buf[17]
    if not 2 <= length <= 512 or length % 2 or length != n - ARTDMX_HEADER:
        raise Malformed(f"length {length} disagrees with the datagram (even, 2..512)")
    universe = (buf[15] << 8) | buf[14]
    return DmxPacket(sender, universe, 100, buf[12] or -1, False, bytes(buf[18:n]))
