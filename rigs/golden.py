"""Golden test vectors: wire bytes in hex with their decoded meaning.

The vector files stay next to the protocol they exemplify, in ``firmware_proto/vectors/*.json``
(:data:`VECTOR_DIR`, beside PROTOCOL.md), where the C firmware's tests read them too
(``firmware/Makefile``); this module, which builds and loads them, is a rig. Regenerate after
an intended protocol change with ``python -m grassd.rigs.golden`` (the test suite checks that
the checked-in files equal what this module builds, and that every vector decodes and
re-encodes exactly).

Files:

* ``messages.json``: one frame of every message type, with its fields.
* ``framing.json``: CRC check values, frames that must be rejected, and a byte stream with
  garbage between frames together with the frames a receiver must extract from it.
* ``transfer.json``: a complete table push (HELLO, GET_STATUS, BEGIN, CHUNKs, COMMIT,
  GET_STATUS) as exchanged with the reference firmware, request and answer per step.
* ``pattern.json``: test patterns (PATTERN, PATTERN_END) with the reference firmware: raw
  lengths with and without a table, the NAKs, a table push and SET_LEVEL held by the pattern,
  PATTERN_END restoring table[level]; request and answer per step.
* ``latch.json``: the frame latch (STAGE_LEVEL, SHOW) with the reference firmware: staging
  moves nothing, a broadcast SHOW (no answer) shows the staged frame, a SHOW of another frame
  shows nothing, a new frame number drops an unshown one, a commit between STAGE and SHOW
  applies at the SHOW, a unicast SHOW is answered; request and answer (null: none) per step.
"""

from __future__ import annotations

import json
import re
import sys
import tempfile
from dataclasses import fields
from pathlib import Path

import numpy as np

from grassd import firmware_proto
from grassd.firmware_proto.codec import Frame, encode_frame, parse_body
from grassd.firmware_proto.crc import crc32_iso_hdlc
from grassd.firmware_proto.framing import BROADCAST_ADDRESS
from grassd.firmware_proto.messages import (
    FEATURE_LATCH,
    FEATURE_PATTERNS,
    MESSAGE_CLASSES,
    Ack,
    GetPositions,
    GetStatus,
    Hello,
    Info,
    MsgType,
    Nak,
    NakCode,
    Pattern,
    PatternEnd,
    Positions,
    SetLevel,
    Show,
    StageLevel,
    TableBegin,
    TableChunk,
    TableCommit,
    TableKind,
    TableStatus,
)
from grassd.firmware_proto.tables import chunk_spans, table_bytes, table_crc

#: Folder holding the vector files: ``vectors/`` of :mod:`grassd.firmware_proto`.
VECTOR_DIR = Path(firmware_proto.__file__).with_name("vectors")


def frame_to_meaning(frame: Frame) -> dict:
    """JSON-able meaning of a frame: header fields, type name and message fields (bytes as hex)."""
    msg = frame.message
    values = {f.name: getattr(msg, f.name) for f in fields(msg)}
    return {
        "version": frame.version, "address": frame.address, "seq": frame.seq,
        "type": msg.TYPE.name,
        "fields": {k: (v.hex() if isinstance(v, bytes) else v) for k, v in values.items()},
    }


def frame_from_meaning(meaning: dict) -> Frame:
    """Inverse of :func:`frame_to_meaning`."""
    cls = MESSAGE_CLASSES[MsgType[meaning["type"]]]
    kinds = {f.name: f.type for f in fields(cls)}
    args = {k: (bytes.fromhex(v) if kinds[k] == "bytes" else v)
            for k, v in meaning["fields"].items()}
    return Frame(meaning["address"], meaning["seq"], cls(**args), meaning["version"])


def _vector(name: str, frame: Frame, note: str = "") -> dict:
    out = {"name": name, "hex": encode_frame(frame).hex(), "meaning": frame_to_meaning(frame)}
    if note:
        out["note"] = note
    return out


def example_table() -> np.ndarray:
    """The table used in the vectors: level v -> round(v * 20000 / 255) um (linear, 0..20 mm)."""
    return np.round(np.arange(256) * 20000 / 255).astype(np.uint16)


def _messages() -> dict:
    t = example_table()
    crc = table_crc(t)
    frames = [
        ("hello", Frame(1, 0x0001, Hello())),
        ("info", Frame(1, 0x0001, Info(1, 1, 0, 0, 0x6A5D0001, 16, 16, 256, 20000,
                                       FEATURE_PATTERNS | FEATURE_LATCH)),
         "features bit 0: test patterns, bit 1: the frame latch (a controller from before "
         "features sends the first 16 payload bytes only, read as features 0)"),
        ("get_status", Frame(1, 0x0002, GetStatus())),
        ("table_status_none", Frame(1, 0x0002, TableStatus(0xFF, 0, 0, 0, 0, 0, 0, 0)),
         "no valid table committed yet"),
        ("table_status_active", Frame(1, 0x0002, TableStatus(1, 0, 1, 42, crc, 7, 1, 256))),
        ("table_begin", Frame(1, 0x0003, TableBegin(42, TableKind.GLOBAL, 1, 512, crc))),
        ("table_chunk", Frame(1, 0x0004, TableChunk(42, 0, table_bytes(t)[:16])),
         "first 8 entries of the example table"),
        ("table_commit", Frame(1, 0x0005, TableCommit(42, crc))),
        ("set_level", Frame(5, 0x0006, SetLevel(2, bytes([0, 128, 255])))),
        ("get_positions", Frame(5, 0x0007, GetPositions(0, 2))),
        ("positions", Frame(5, 0x0007, Positions(0, bytes.fromhex("e02ee02e00000000"))),
         "pixel 0 at 12000 um target 12000, pixel 1 at 0 target 0"),
        ("pattern", Frame(5, 0x0008, Pattern(30, 1, _lengths([5000, 20000]))),
         "pixels 1 and 2 to 5 mm and 20 mm for 3.0 s after this frame"),
        ("pattern_end", Frame(5, 0x0009, PatternEnd())),
        ("stage_level", Frame(5, 0x000A, StageLevel(0x0102, 2, bytes([0, 128, 255]))),
         "levels of pixels 2..4 for frame 0x0102, shown at its SHOW"),
        ("show_broadcast", Frame(BROADCAST_ADDRESS, 0x000B, Show(0x0102)),
         "address 0: every controller that staged frame 0x0102 shows it; none answers"),
        ("nak_pattern_value_range", Frame(5, 0x0008, Nak(MsgType.PATTERN, NakCode.VALUE_RANGE,
                                                          1)),
         "the second length of the frame is over max_length_um"),
        ("ack", Frame(1, 0x0004, Ack(MsgType.TABLE_CHUNK))),
        ("nak_incomplete", Frame(1, 0x0005, Nak(MsgType.TABLE_COMMIT, NakCode.INCOMPLETE, 256)),
         "commit refused: bytes from offset 256 missing"),
        ("zero_heavy", Frame(247, 0xFF00, TableChunk(0, 0, bytes(300))),
         "300 zero bytes: COBS overhead stays one byte per 254"),
        ("cobs_full_block", Frame(1, 0x0101, TableChunk(0, 0, bytes([1, *range(1, 250)]))),
         "body + CRC end in a run of 254 non-zero bytes: its 0xFF block ends the frame, no "
         "code byte follows (PROTOCOL.md section 2)"),
    ]
    return {
        "description": "One frame of every message type. hex = wire bytes including the final "
                       "0x00 delimiter; meaning = decoded header and fields (byte fields in hex).",
        "vectors": [_vector(*f) for f in frames],
    }


def _framing() -> dict:
    good = encode_frame(Frame(1, 0x0102, GetStatus()))
    bad_crc = bytearray(good)
    bad_crc[3] ^= 0x01
    stream = (b"\x13\x37garbage" + b"\x00" + good + b"\x00\x00" + bytes(bad_crc)
              + b"\x05\x01" + b"\x00" + encode_frame(Frame(2, 0x0103, Hello())))
    return {
        "description": "Framing: CRC check values, frames a receiver must drop, and a stream "
                       "with garbage from which exactly the listed frames must be extracted.",
        "crc": [{"name": "CRC-32/ISO-HDLC", "input_ascii": "123456789",
                 "check": f"{crc32_iso_hdlc(b'123456789'):#010x}",
                 "used_for": "frame trailer, table_crc, bank headers"}],
        "rejected": [
            {"name": "bad_crc", "hex": bytes(bad_crc).hex(), "why": "one bit flipped"},
            {"name": "too_short", "hex": "030102" "00", "why": "body shorter than 9 bytes"},
            {"name": "bad_cobs", "hex": "05010200", "why": "COBS code byte points past the end"},
            {"name": "oversized", "hex": ("ff" + "01" * 1100 + "00"),
             "why": "longer than 1039 bytes without a delimiter"},
        ],
        "stream": {"hex": stream.hex(),
                   "frames": [frame_to_meaning(Frame(1, 0x0102, GetStatus())),
                              frame_to_meaning(Frame(2, 0x0103, Hello()))]},
    }


def _lengths(um: list[int]) -> bytes:
    return np.asarray(um, dtype="<u2").tobytes()


def _conversation(requests: list, seq0: int) -> list[dict]:
    """Each request (seq ``seq0 + i``) to a fresh controller at address 3 (16 pixels, clock
    stopped at 0: no motion, no watchdog), with the answer's wire bytes and meaning (None for
    a broadcast, which is never answered). A request may be ``(address, message)``."""
    from grassd.firmware_proto.framing import FrameReader
    from grassd.rigs.firmware import Controller, ControllerConfig

    steps = []
    with tempfile.TemporaryDirectory() as tmp:
        ctl = Controller(ControllerConfig(address=3, n_pixels=16), Path(tmp) / "e.eeprom",
                         clock=lambda: 0.0)
        reader = FrameReader()
        for i, req in enumerate(requests):
            address, req = req if isinstance(req, tuple) else (3, req)
            frame = Frame(address, seq0 + i, req)
            wire = encode_frame(frame)
            (body,) = reader.feed(wire)
            answer = ctl.handle(body)
            step = {"request": {"hex": wire.hex(), "meaning": frame_to_meaning(frame)},
                    "answer": None}
            if answer is not None:
                (answer_body,) = FrameReader().feed(answer)
                step["answer"] = {"hex": answer.hex(),
                                  "meaning": frame_to_meaning(parse_body(answer_body))}
            steps.append(step)
        ctl.close()
    return steps


def _transfer() -> dict:
    t = example_table()
    data, crc = table_bytes(t), table_crc(t)
    requests = [Hello(), GetStatus(), TableBegin(0x2A, TableKind.GLOBAL, 1, len(data), crc)]
    requests += [TableChunk(0x2A, o, data[o:o + n]) for o, n in chunk_spans(len(data), 256)]
    requests += [TableCommit(0x2A, crc), GetStatus()]
    steps = _conversation(requests, 0x0100)
    return {
        "description": "A fresh controller (address 3, 16 pixels, max_chunk 256) receives the "
                       "example table (level v -> round(v*20000/255) um) as table_id 0x2A in two "
                       "256-byte chunks; each step is a request and the firmware's answer.",
        "table_um": t.tolist(),
        "table_crc": f"{crc:#010x}",
        "steps": steps,
    }


def _pattern() -> dict:
    t = example_table()
    data, crc = table_bytes(t), table_crc(t)
    four = GetPositions(0, 4)
    requests = [
        Hello(), PatternEnd(),  # ACK outside pattern mode too
        Pattern(50, 1, _lengths([5000, 20000])), four,  # without a table
        Pattern(50, 0, _lengths([100, 20001])),  # NAK VALUE_RANGE 1: nothing changes
        Pattern(50, 15, _lengths([1, 2])),  # NAK BAD_PIXEL 16
        Pattern(0, 0, _lengths([1])),  # NAK BAD_PAYLOAD 0: timeout 0
        TableBegin(0x2A, TableKind.GLOBAL, 1, len(data), crc),
        *[TableChunk(0x2A, o, data[o:o + n]) for o, n in chunk_spans(len(data), 256)],
        TableCommit(0x2A, crc), SetLevel(0, bytes([0, 64, 128, 255])),
        four,  # the pattern still holds every pixel
        Pattern(50, 3, _lengths([7000])), four,  # re-armed; pixel 3 joins it
        PatternEnd(), four,  # table[level] for the levels SET_LEVEL gave
        PatternEnd(), GetStatus(),
    ]
    return {
        "description": "Test patterns with a fresh controller (address 3, 16 pixels, "
                       "max_length_um 20000, clock stopped: motors at 0, no watchdog): raw "
                       "lengths without a table, the NAKs, the example table pushed and "
                       "SET_LEVEL sent during the pattern (no target moves), PATTERN_END "
                       "restoring table[level]; GET_POSITIONS shows (position, target) pairs.",
        "table_um": t.tolist(),
        "steps": _conversation(requests, 0x0200),
    }


def _latch() -> dict:
    t = example_table()
    data, crc = table_bytes(t), table_crc(t)
    half = (t // 2).astype(np.uint16)
    hdata, hcrc = table_bytes(half), table_crc(half)
    four = GetPositions(0, 4)
    show = (BROADCAST_ADDRESS, Show(7))
    requests = [
        Hello(), StageLevel(7, 0, bytes([255])),  # NAK NO_TABLE: nothing staged
        TableBegin(0x2A, TableKind.GLOBAL, 1, len(data), crc),
        *[TableChunk(0x2A, o, data[o:o + n]) for o, n in chunk_spans(len(data), 256)],
        TableCommit(0x2A, crc),
        StageLevel(7, 0, bytes([0, 64, 128, 255])), four,  # staged: no target moves
        (BROADCAST_ADDRESS, Show(6)), four,  # another frame: nothing shown, staging dropped
        StageLevel(7, 0, bytes([0, 64, 128, 255])), show, four,  # shown at once
        show, four,  # shown already: a second SHOW changes nothing
        StageLevel(8, 0, bytes([10, 10])), StageLevel(9, 2, bytes([200, 200])),  # 8 dropped
        (BROADCAST_ADDRESS, Show(9)), four,  # only frame 9's pixels 2, 3 move
        StageLevel(10, 0, bytes([255, 255, 255, 255])),
        TableBegin(0x2B, TableKind.GLOBAL, 1, len(hdata), hcrc),
        *[TableChunk(0x2B, o, hdata[o:o + n]) for o, n in chunk_spans(len(hdata), 256)],
        TableCommit(0x2B, hcrc), four,  # committed: nothing moves until the SHOW
        Show(10), four,  # to its address: answered ACK; table 0x2B's lengths
        StageLevel(11, 15, bytes([1, 2])),  # NAK BAD_PIXEL 16
        (BROADCAST_ADDRESS, SetLevel(0, bytes([0]))), four,  # broadcast other than SHOW: ignored
    ]
    return {
        "description": "The frame latch with a fresh controller (address 3, 16 pixels, clock "
                       "stopped: motors at 0): STAGE_LEVEL moves nothing, a broadcast SHOW "
                       "(address 0, answer null) shows the staged frame, a SHOW of another "
                       "frame or a new frame number drops what is staged, a table committed "
                       "between STAGE and SHOW is the one shown; GET_POSITIONS shows (position, "
                       "target) pairs.",
        "table_um": t.tolist(),
        "steps": _conversation(requests, 0x0300),
    }


def build_vectors() -> dict[str, dict]:
    """Every vector file's content, keyed by file name."""
    return {"messages.json": _messages(), "framing.json": _framing(),
            "transfer.json": _transfer(), "pattern.json": _pattern(), "latch.json": _latch()}


def load_vectors() -> dict[str, dict]:
    """The checked-in vector files, keyed by file name."""
    return {p.name: json.loads(p.read_text()) for p in sorted(VECTOR_DIR.glob("*.json"))}


def main(argv: list[str] | None = None) -> int:
    """Write the vector files into :data:`VECTOR_DIR`."""
    VECTOR_DIR.mkdir(exist_ok=True)
    for name, doc in build_vectors().items():
        text = json.dumps(doc, indent=1)
        text = re.sub(r"\[\s+([-\d,\s]+?)\s+\]", lambda m: "[" + " ".join(m.group(1).split()) + "]",
                      text)  # keep integer lists on one line
        (VECTOR_DIR / name).write_text(text + "\n")
        print(f"wrote {VECTOR_DIR / name}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
