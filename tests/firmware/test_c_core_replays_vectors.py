"""The C firmware core replays every golden vector (firmware_proto/vectors/*.json) byte-exact:
message encode/decode, rejected frames, a stream with garbage, a whole table transfer and a
test-pattern conversation with each answer equal to the Python reference's (plus, in
test_vectors.c, the pattern's watchdog across the wrap of hal millis and a reboot in pattern
mode). Built with the system C compiler."""

from __future__ import annotations

import re
import subprocess

import pytest
from firmware_tiers import missing_reason

from grassd.rigs.golden import load_vectors
from grassd.rigs.native_build import build_firmware

pytestmark = pytest.mark.skipif(missing_reason("posix") is not None,
                                reason=str(missing_reason("posix")))


def test_c_core_replays_every_vector():
    exe = build_firmware("build/test_vectors", "test_vectors")
    proc = subprocess.run([str(exe)], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    m = re.search(r"(\d+) checks, 0 failed: (\d+) message vectors, (\d+) rejected frames, "
                  r"(\d+) stream frames, (\d+) transfer steps, (\d+) pattern steps", proc.stdout)
    assert m, proc.stdout
    v = load_vectors()
    # every vector in the files was compiled in (the header is generated from them)
    assert [int(x) for x in m.groups()[1:]] == [
        len(v["messages.json"]["vectors"]), len(v["framing.json"]["rejected"]),
        len(v["framing.json"]["stream"]["frames"]), len(v["transfer.json"]["steps"]),
        len(v["pattern.json"]["steps"])]
