"""The checksums of the protocol, named by their catalogue names (Greg Cook's CRC catalogue).

>>> hex(crc32_iso_hdlc(b"123456789"))  # the catalogue's check value
'0xcbf43926'
"""

from __future__ import annotations

import zlib

#: CRC-32/ISO-HDLC check value: the CRC of the ASCII bytes "123456789".
CRC32_ISO_HDLC_CHECK = 0xCBF43926


def crc32_iso_hdlc(data: bytes | bytearray | memoryview, crc: int = 0) -> int:
    """CRC-32/ISO-HDLC (poly 0x04C11DB7 reflected, init/xorout 0xFFFFFFFF) of ``data``.

    This is ``zlib.crc32``; pass the previous result as ``crc`` to continue over more data.
    """
    return zlib.crc32(data, crc) & 0xFFFFFFFF
