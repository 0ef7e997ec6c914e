"""The numbers the C firmware and the Python side both write are the same: a controller's
defaults (firmware/core/board_defaults.h against the Python reference's ControllerConfig and
SIM_UID_BASE) and the protocol's sizes (firmware/core/limits.h against firmware_proto's
constants). The C headers are read as text: no compiler needed."""

from __future__ import annotations

import re
from dataclasses import fields
from pathlib import Path

from grassd.firmware_proto import framing, messages
from grassd.rigs import eeprom
from grassd.rigs.firmware import SIM_UID_BASE, ControllerConfig

CORE = Path(__file__).resolve().parents[2] / "firmware" / "core"


def c_defines(header: str) -> dict[str, int]:
    """The object-like ``#define FW_NAME value`` lines of a core header whose value is an
    integer expression of integers and earlier such defines, evaluated (C's unsigned division
    of these positive numbers is Python's //)."""
    out: dict[str, int] = {}
    for m in re.finditer(r"^#define\s+(FW_\w+)[ \t]+(.+?)\s*(?:/\*.*)?$",
                         (CORE / header).read_text(), re.M):
        expr = re.sub(r"\b(0x[0-9A-Fa-f]+|\d+)u\b", r"\1", m.group(2))
        expr = re.sub(r"\bFW_\w+\b", lambda n: str(out.get(n.group(0), "?")), expr)
        if re.fullmatch(r"[0-9A-Fa-fx()+\-* /]+", expr):
            out[m.group(1)] = eval(expr.replace("/", "//"))  # noqa: S307 - digits and operators
    return out


def test_python_defaults_equal_the_c_board_defaults():
    c = c_defines("board_defaults.h")
    py = {f.name: f.default for f in fields(ControllerConfig)}
    assert py["address"] == c["FW_DEFAULT_ADDRESS"]
    assert SIM_UID_BASE == c["FW_DEFAULT_UID_BASE"]
    assert py["uid"] == c["FW_DEFAULT_UID_BASE"] + c["FW_DEFAULT_ADDRESS"]
    assert py["n_pixels"] == c["FW_DEFAULT_PIXELS"]
    assert py["max_chunk"] == c["FW_DEFAULT_MAX_CHUNK"]
    assert py["max_length_um"] == c["FW_DEFAULT_MAX_LENGTH_UM"]


def test_python_protocol_sizes_equal_the_c_limits():
    c = c_defines("limits.h")
    assert c["FW_PROTOCOL_VERSION"] == messages.PROTOCOL_VERSION
    assert c["FW_HEADER_SIZE"] == framing.HEADER_SIZE
    assert c["FW_CRC_SIZE"] == framing.CRC_SIZE
    assert c["FW_MAX_PAYLOAD"] == framing.MAX_PAYLOAD
    assert c["FW_MAX_POSITIONS"] == messages.MAX_POSITIONS
    assert (c["FW_MIN_ADDRESS"], c["FW_MAX_ADDRESS"]) == (framing.MIN_ADDRESS,
                                                          framing.MAX_ADDRESS)
    assert c["FW_NO_BANK"] == messages.NO_BANK
    assert c["FW_TABLE_ENTRIES"] == messages.TABLE_ENTRIES
    assert c["FW_TABLE_BYTES"] == messages.TABLE_BYTES
    assert c["FW_BANK_HEADER_SIZE"] == eeprom.BANK_HEADER_SIZE
    assert c["FW_BANK_MAGIC"] == eeprom.BANK_MAGIC
    assert c["FW_MAX_CHUNK_DATA"] == messages.MAX_CHUNK_DATA
    assert c["FW_MAX_ENCODED"] == framing.MAX_ENCODED
