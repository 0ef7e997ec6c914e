"""`make -C firmware teensy`: the Teensy 4.1 sketch, with the current core, compiled and linked
for its Cortex-M7 by Debian's arm-none-eabi-g++ against our stand-ins for the Arduino and PJRC
calls it makes (firmware/test/arduino_stubs), its size printed, and no heap in its images.
What this compile does not prove is in firmware/README.md."""

from __future__ import annotations

import fcntl
import re
import subprocess
from pathlib import Path

import pytest
from firmware_tiers import teensy_missing

from grassd.rigs.native_build import BUILD_DIR, FIRMWARE_DIR

#: what would link a heap: newlib's allocator and sbrk, operator new and delete (mangled)
HEAP = re.compile(r"^_?_?(malloc|calloc|realloc|free|sbrk)(_r)?$|^_Zn[wa]j|^_Zd[la]Pv")
#: a line of arm-none-eabi-size: text data bss dec hex filename
SIZE_LINE = r"^\s*(\d+)\s+(\d+)\s+(\d+)\s+\d+\s+[0-9a-f]+\s+\S*{name}$"


pytestmark = pytest.mark.skipif(teensy_missing() is not None, reason=str(teensy_missing()))


def _make_teensy(*args: str) -> subprocess.CompletedProcess:
    """`make -s -C firmware teensy ARGS`, under the lock the other firmware builds take."""
    BUILD_DIR.mkdir(exist_ok=True)
    with open(BUILD_DIR / ".lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        return subprocess.run(["make", "-s", "--no-print-directory", "-C", str(FIRMWARE_DIR),
                               "teensy", *args], capture_output=True, text=True, timeout=300)


def _defined_symbols(elf: Path) -> list[tuple[str, str]]:
    """(type letter, name) of every symbol `elf` defines, as arm-none-eabi-nm lists them."""
    out = subprocess.run(["arm-none-eabi-nm", "--defined-only", str(elf)], capture_output=True,
                         text=True, check=True).stdout
    return [(f[-2], f[-1]) for f in (line.split() for line in out.splitlines()) if len(f) >= 2]


def test_sketch_links_with_the_current_core_prints_its_size_and_has_no_heap():
    proc = _make_teensy()
    assert proc.returncode == 0, proc.stdout + proc.stderr
    out = proc.stdout
    assert "arm-none-eabi-size, Teensy 4.1 sketch" in out, out
    text, data, bss = map(int, re.search(SIZE_LINE.format(name=r"grassfw-teensy41\.elf"), out,
                                         re.M).groups())
    ours = re.search(r"the sketch and the core alone: flash \(text\+data\) (\d+) B.*"
                     r"static RAM \(data\+bss\) (\d+) B", out)
    assert ours, out
    flash, ram = map(int, ours.groups())
    # the core's budget (firmware/README.md: <= 32 KiB flash, <= 24 KiB RAM), here with the
    # sketch; the image holds them and the stand-ins, and fits the DTCM it is linked into
    assert 0 < flash <= 32 * 1024 and 0 < ram <= 24 * 1024, out
    assert flash <= text + data and ram <= data + bss <= 512 * 1024, out
    assert re.search(r"RS-485 variant \(Serial1 \+ DE pin\): text \d+ data \d+ bss \d+", out), out

    image = BUILD_DIR / "teensy41-image"
    for elf in (image / "grassfw-teensy41.elf", image / "grassfw-teensy41-rs485.elf"):
        symbols = _defined_symbols(elf)
        names = {name for _, name in symbols}
        heap = sorted(name for name in names if HEAP.search(name))
        assert not heap, f"{elf.name} links the heap: {heap}"
        # setup() and loop() (C++ names), the protocol's entry points, the frame latch of the
        # current core among them
        assert {"_Z5setupv", "_Z4loopv", "fw_boot", "fw_rx_feed", "fw_tick", "fw_poll",
                "fw_latch_stage", "fw_latch_take", "fw_irq_save"} <= names, elf.name
        # the encoders are one static array in zeroed RAM, not objects made at run time
        kinds = {kind for kind, name in symbols if name == "_ZL8encoders"}
        assert kinds and kinds <= {"b", "B"}, (elf.name, kinds)


def test_heap_check_fails_the_build_on_an_operator_new(tmp_path):
    """The same build with one `new` linked in (a static object made by operator new) stops
    with the heap's symbols named, so the check above can see a heap when there is one."""
    probe = tmp_path / "probe.cpp"
    probe.write_text("int *grass_probe = new int(7);\n")
    proc = _make_teensy(f"TEENSY_EXTRA={probe}", f"TEENSY_IMG={tmp_path / 'image'}")
    assert proc.returncode != 0, proc.stdout
    assert "links the heap" in proc.stderr and "_Znwj" in proc.stderr, proc.stderr
    assert "grassfw-teensy41.elf" in proc.stderr, proc.stderr
