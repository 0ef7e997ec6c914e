"""Codec of the controller protocol: round trips, golden vectors, fuzzing, tables, table files."""

from __future__ import annotations

import json
import re
import struct
from dataclasses import fields

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from grassd.firmware_proto.codec import Frame, decode_frame, encode_frame, parse_body
from grassd.firmware_proto.crc import CRC32_ISO_HDLC_CHECK, crc32_iso_hdlc
from grassd.firmware_proto.errors import FrameError, TableError, TableFileError
from grassd.firmware_proto.framing import MAX_ENCODED, FrameReader, decode_body, encode_body
from grassd.firmware_proto.messages import MESSAGE_CLASSES, TableKind
from grassd.firmware_proto.table_file import load_table_file
from grassd.firmware_proto.tables import (
    as_table_array,
    chunk_spans,
    table_bytes,
    table_crc,
    table_from_bytes,
)
from grassd.rigs.golden import (
    build_vectors,
    frame_from_meaning,
    frame_to_meaning,
    load_vectors,
)

_INT = {"B": 0xFF, "H": 0xFFFF, "I": 0xFFFFFFFF}


def message_strategy(cls):
    """Any valid message of ``cls``: fixed fields over their full range, tails of legal size."""
    fixed = [st.integers(0, _INT[c]) for c in cls._FMT[1:]]
    if cls._TAIL is not None:
        step = cls._TAIL_STEP
        sizes = st.integers(cls._TAIL_MIN // step, cls._TAIL_MAX // step).map(lambda k: k * step)
        fixed.append(sizes.flatmap(lambda n: st.binary(min_size=n, max_size=n)))
    return st.tuples(*fixed).map(lambda vals: cls(*vals))


frames = st.builds(
    Frame,
    address=st.integers(0, 255),
    seq=st.integers(0, 0xFFFF),
    message=st.sampled_from(sorted(MESSAGE_CLASSES.values(), key=lambda c: c.TYPE))
    .flatmap(message_strategy),
)


def test_crc_check_values():
    assert crc32_iso_hdlc(b"123456789") == CRC32_ISO_HDLC_CHECK == 0xCBF43926
    assert crc32_iso_hdlc(b"56789", crc32_iso_hdlc(b"1234")) == CRC32_ISO_HDLC_CHECK


@pytest.mark.parametrize("cls", sorted(MESSAGE_CLASSES.values(), key=lambda c: c.TYPE),
                         ids=lambda c: c.TYPE.name)
@settings(max_examples=60, deadline=None)
@given(data=st.data())
def test_round_trip_every_message_type(cls, data):
    frame = Frame(data.draw(st.integers(1, 247)), data.draw(st.integers(0, 0xFFFF)),
                  data.draw(message_strategy(cls)))
    wire = encode_frame(frame)
    assert wire.endswith(b"\x00") and wire.count(0) == 1
    assert len(wire) <= MAX_ENCODED + 1
    assert decode_frame(wire[:-1]) == frame
    assert FrameReader().feed(b"\x00junk\x00" + wire + wire) == [wire_body(frame)] * 2


def wire_body(frame: Frame) -> bytes:
    return decode_body(encode_frame(frame)[:-1])


def test_out_of_range_fields_are_codec_errors():
    from grassd.firmware_proto.messages import Hello, SetLevel, TableChunk

    with pytest.raises(FrameError):
        encode_frame(Frame(256, 0, Hello()))
    with pytest.raises(FrameError):
        encode_frame(Frame(1, 0x10000, Hello()))
    with pytest.raises(FrameError):
        TableChunk(1, 0, b"").pack()
    with pytest.raises(FrameError):
        TableChunk(1, 0, bytes(1017)).pack()
    with pytest.raises(FrameError):
        SetLevel(-1, b"\x01").pack()


def test_vector_files_are_what_the_codec_builds():
    """The checked-in vectors equal a fresh build: the codec has not drifted from them."""
    assert load_vectors() == json.loads(json.dumps(build_vectors()))


def test_message_vectors_decode_to_their_meaning_and_reencode_exactly():
    vectors = load_vectors()["messages.json"]["vectors"]
    types = {v["meaning"]["type"] for v in vectors}
    assert types == {c.TYPE.name for c in MESSAGE_CLASSES.values()}
    for v in vectors:
        wire = bytes.fromhex(v["hex"])
        frame = decode_frame(wire[:-1])
        assert frame_to_meaning(frame) == v["meaning"], v["name"]
        assert encode_frame(frame_from_meaning(v["meaning"])) == wire, v["name"]


def test_transfer_vectors_are_a_consistent_conversation():
    doc = load_vectors()["transfer.json"]
    table = np.array(doc["table_um"], dtype=np.uint16)
    assert f"{table_crc(table):#010x}" == doc["table_crc"]
    staged = bytearray(512)
    for step in doc["steps"]:
        for side in ("request", "answer"):
            wire = bytes.fromhex(step[side]["hex"])
            frame = decode_frame(wire[:-1])
            assert frame_to_meaning(frame) == step[side]["meaning"]
            assert encode_frame(frame) == wire
        req = decode_frame(bytes.fromhex(step["request"]["hex"])[:-1])
        if req.message.TYPE.name == "TABLE_CHUNK":
            m = req.message
            staged[m.offset:m.offset + len(m.data)] = m.data
    assert bytes(staged) == table_bytes(table)
    final = step["answer"]["meaning"]
    assert final["type"] == "TABLE_STATUS"
    assert final["fields"]["table_id"] == 0x2A
    assert final["fields"]["table_crc"] == table_crc(table)


def test_framing_vectors():
    doc = load_vectors()["framing.json"]
    assert int(doc["crc"][0]["check"], 16) == crc32_iso_hdlc(b"123456789")
    for v in doc["rejected"]:
        reader = FrameReader()
        assert reader.feed(bytes.fromhex(v["hex"])) == [], v["name"]
        assert reader.stats.bad + reader.stats.oversized == 1, v["name"]
    bodies = FrameReader().feed(bytes.fromhex(doc["stream"]["hex"]))
    assert [frame_to_meaning(parse_body(b)) for b in bodies] == doc["stream"]["frames"]


@pytest.mark.timeout(60)
@settings(max_examples=400, deadline=None)
@given(st.binary(max_size=2000))
def test_fuzz_decode_frame_raises_only_frame_error(data):
    try:
        decode_frame(data)
    except FrameError:
        pass


@pytest.mark.timeout(60)
@settings(max_examples=600, deadline=None)
@given(st.binary(max_size=1100), st.integers(0, 255), st.booleans())
def test_fuzz_bodies_with_valid_crc_raise_only_frame_error(body, msg_type, steer):
    """Past COBS and CRC: random headers and payloads (half steered to version 1, known type)."""
    if steer and len(body) >= 3:
        body = bytes([1, body[1], msg_type]) + body[3:]
    try:
        wire = encode_body(body)
    except FrameError:
        return
    try:
        frame = decode_frame(wire[:-1])
    except FrameError:
        return
    assert encode_frame(frame) == wire  # whatever decodes re-encodes to the same bytes


@pytest.mark.timeout(60)
@settings(max_examples=300, deadline=None)
@given(st.lists(st.binary(max_size=600), max_size=8), frames)
def test_fuzz_stream_never_raises_and_resyncs(chunks, frame):
    """Random bytes fed in random pieces never raise, memory stays bounded, and a frame sent
    after a delimiter is always recovered."""
    reader = FrameReader()
    for chunk in chunks:
        for body in reader.feed(chunk):
            try:
                parse_body(body)
            except FrameError:
                pass
        assert len(reader._buffer) <= MAX_ENCODED
    assert reader.feed(b"\x00" + encode_frame(frame)) == [wire_body(frame)]


@settings(max_examples=200, deadline=None)
@given(frames, st.integers(0, 10_000), st.integers(0, 7))
def test_single_bit_flip_is_always_detected(frame, pos, bit):
    wire = bytearray(encode_frame(frame)[:-1])
    wire[pos % len(wire)] ^= 1 << bit
    try:
        got = decode_frame(bytes(wire))
    except FrameError:
        return
    pytest.fail(f"flipped frame decoded as {got}")


def test_oversized_run_is_discarded_and_reader_recovers():
    reader = FrameReader()
    frame = Frame(1, 1, MESSAGE_CLASSES[0x01]())
    for _ in range(5):
        assert reader.feed(b"\x01" * 700) == []
    assert reader.stats.oversized == 1 and len(reader._buffer) == 0
    assert reader.feed(b"\x00" + encode_frame(frame)) == [wire_body(frame)]


def test_encode_body_limits():
    with pytest.raises(FrameError):
        encode_body(bytes(1030))
    assert decode_body(encode_body(bytes(1029))[:-1]) == bytes(1029)


def test_message_fields_match_spec_sizes():
    """Payload sizes as in PROTOCOL.md §3 (firmware authors size their structs from them)."""
    sizes = {"INFO": 18, "TABLE_STATUS": 21, "TABLE_BEGIN": 15, "TABLE_COMMIT": 8, "ACK": 1,
             "NAK": 6, "GET_POSITIONS": 4, "HELLO": 0, "GET_STATUS": 0}
    for cls in MESSAGE_CLASSES.values():
        if cls.TYPE.name in sizes:
            assert struct.calcsize(cls._FMT) == sizes[cls.TYPE.name], cls
            assert len(fields(cls)) == len(cls._FMT) - 1 + (cls._TAIL is not None)


# --- tables ---------------------------------------------------------------------------------

def test_table_bytes_round_trip_and_crc():
    rng = np.random.default_rng(0)
    g = rng.integers(0, 20001, 256).astype(np.uint16)
    p = rng.integers(0, 20001, (5, 256)).astype(np.uint16)
    assert np.array_equal(table_from_bytes(table_bytes(g), 1), g)
    assert np.array_equal(table_from_bytes(table_bytes(p), 5, TableKind.PER_PIXEL), p)
    assert table_bytes(g)[:2] == int(g[0]).to_bytes(2, "little")
    assert table_crc(g) == crc32_iso_hdlc(g.astype("<u2").tobytes())
    assert chunk_spans(512, 200) == [(0, 200), (200, 200), (400, 112)]


@pytest.mark.parametrize("bad", [np.zeros(255), np.zeros((2, 3, 256)), np.full(256, -1),
                                 np.full(256, 70000), np.full(256, 0.5), np.full(256, np.nan),
                                 np.array(["a"] * 256)])
def test_invalid_tables_are_refused(bad):
    with pytest.raises(TableError):
        as_table_array(bad)


def test_table_files(tmp_path):
    t = np.arange(256) * 50
    (tmp_path / "a.json").write_text(json.dumps(t.tolist()))
    (tmp_path / "b.json").write_text(json.dumps({"lengths_um": [t.tolist()] * 3, "table_id": 9}))
    (tmp_path / "c.csv").write_text("# lengths\n" + ",".join(map(str, t)) + "\n")
    (tmp_path / "d.csv").write_text("\n".join(" ".join(map(str, t[i:i + 16]))
                                              for i in range(0, 256, 16)))
    (tmp_path / "e.csv").write_text("\n".join(",".join(map(str, t)) for _ in range(2)))
    arr, tid = load_table_file(tmp_path / "a.json")
    assert tid is None and np.array_equal(arr, t)
    arr, tid = load_table_file(tmp_path / "b.json")
    assert tid == 9 and arr.shape == (3, 256)
    assert np.array_equal(load_table_file(tmp_path / "c.csv")[0], t)
    assert np.array_equal(load_table_file(tmp_path / "d.csv")[0], t)
    assert load_table_file(tmp_path / "e.csv")[0].shape == (2, 256)


@pytest.mark.parametrize("name,text,fragment", [
    ("x.json", "[1, 2", "not valid JSON"),
    ("x.json", '{"lengths": []}', "expected keys"),
    ("x.json", '{"lengths_um": [], "table_id": -1}', "table_id"),
    ("x.json", "[[1, 2], [3]]", "x.json"),
    ("x.csv", "1,2,three", "x.csv:1"),
    ("x.csv", ",".join(["5"] * 255), "256 values"),
    ("x.csv", ",".join(["99999"] * 256), "0..65535"),
])
def test_bad_table_files_name_the_problem(tmp_path, name, text, fragment):
    (tmp_path / name).write_text(text)
    with pytest.raises(TableFileError, match=fragment):
        load_table_file(tmp_path / name)
    with pytest.raises(TableFileError, match="cannot read"):
        load_table_file(tmp_path / "missing.json")


def test_protocol_md_worked_example_matches_the_codec():
    from pathlib import Path

    import grassd.firmware_proto as pkg
    from grassd.firmware_proto.messages import Hello

    text = (Path(pkg.__file__).with_name("PROTOCOL.md")).read_text()
    (hex_bytes,) = re.findall(r"^ +wire +([0-9a-f ]+)$", text, flags=re.M)
    assert bytes.fromhex(hex_bytes) == encode_frame(Frame(1, 1, Hello()))
