"""Bad bytes: the C core built with -fsanitize=address,undefined takes 10^6 random and mutated
frames (valid, mutated behind a valid CRC, damaged on the line, garbage) on a two-controller
bus without a crash, an out-of-bounds access or undefined behaviour; every answer is a valid
frame from the addressed controller."""

from __future__ import annotations

import re
import subprocess

import pytest
from firmware_tiers import missing_reason

from grassd.rigs.native_build import build_firmware

pytestmark = pytest.mark.skipif(missing_reason("posix") is not None,
                                reason=str(missing_reason("posix")))


def test_a_million_bad_frames_under_sanitizers():
    exe = build_firmware("build/fuzz", "fuzz")
    proc = subprocess.run([str(exe), "1000000", "7"], capture_output=True, text=True,
                          timeout=300)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    m = re.search(r"fuzz: (\d+) frames \((\d+) valid, (\d+) mutated with valid CRC, (\d+) "
                  r"damaged on the line, (\d+) garbage\).* (\d+) failures", proc.stdout)
    assert m, proc.stdout
    frames, *kinds, failures = (int(x) for x in m.groups())
    assert frames == 1_000_000 and failures == 0 and min(kinds) > 200_000
    assert "runtime error" not in proc.stderr and "AddressSanitizer" not in proc.stderr
