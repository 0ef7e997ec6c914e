"""`grassd controllers sim --firmware qemu`: N QEMU instances of the Cortex-M7 image joined into
one RS-485-style bus by the relay, in its own process; the host scans them all and pushes."""

from __future__ import annotations

import re
import signal
import subprocess
import sys

import numpy as np
import pytest
from firmware_tiers import missing_reason, teensy_missing

from grassd.firmware_proto.client import ControllerClient, RetryPolicy
from grassd.firmware_proto.tables import table_crc

pytestmark = pytest.mark.skipif(missing_reason("qemu") is not None,
                                reason=str(missing_reason("qemu")))


def test_sim_command_joins_qemu_instances_into_one_bus(tmp_path):
    proc = subprocess.Popen(
        [sys.executable, "-c", "from grassd.daemon.cli.main import main; main()", "controllers",
         "sim", "--firmware", "qemu", "--count", "3", "--pixels", "16",
         "--state-dir", str(tmp_path / "sim")],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        line = proc.stdout.readline()
        assert "addresses 1-3, 16 pixels each" in line, line + proc.stderr.read()
        path = line.split(" -> ")[0]
        t = np.random.default_rng(2).integers(0, 20001, (16, 256)).astype(np.uint16)
        with ControllerClient(path, policy=RetryPolicy(timeout_s=0.3)) as c:
            found = c.scan(range(1, 6), timeout_s=0.1)
            assert sorted(found) == [1, 2, 3]
            assert all(i.n_pixels == 16 and i.max_chunk == 256 for i in found.values())
            assert c.push_table(2, t, table_id=9).table_crc == table_crc(t)
            assert c.read_status(1).active_bank == 0xFF  # only the addressed one took it
            c.set_levels(2, list(range(0, 256, 16)))
            assert c.read_positions(2)[:, 1].tolist() == [int(t[p, 16 * p]) for p in range(16)]
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=20)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, err


def test_cortex_m7_core_fits_its_flash_and_ram_budget():
    """The core for the Cortex-M7 (16 pixels of per-pixel tables): <= 32 KiB flash and one
    controller's RAM <= 24 KiB, as arm-none-eabi-size and nm report for the mps2 build."""
    from grassd.rigs.native_build import BUILD_DIR, mps2_image

    mps2_image()
    text = (BUILD_DIR / "mps2" / "size.txt").read_text()
    flash = int(re.search(r"core flash \(text\+data\) (\d+) B", text).group(1))
    static = int(re.search(r"static RAM \(data\+bss\) (\d+) B", text).group(1))
    ctl = int(re.search(r"one fw_controller .* (\d+) B", text).group(1))
    assert flash <= 32 * 1024 and static + ctl <= 24 * 1024, text


@pytest.mark.skipif(teensy_missing() is not None, reason=str(teensy_missing()))
def test_teensy_sketch_carries_the_tested_core(tmp_path):
    """`make -C firmware teensy41` assembles a sketch whose core is byte for byte firmware/core
    and compiles for the Teensy 4.1's Cortex-M7 with the sketch's own settings (8 pixels)."""
    from grassd.rigs.native_build import BUILD_DIR, FIRMWARE_DIR, build_firmware

    build_firmware("teensy41", "teensy41")
    core = BUILD_DIR / "teensy41" / "grassfw_teensy41" / "src" / "core"
    for src in sorted((FIRMWARE_DIR / "core").glob("*.[ch]")):
        assert (core / src.name).read_bytes() == src.read_bytes(), src.name
    check = tmp_path / "check.c"
    check.write_text('#include "controller.h"\n'
                     '_Static_assert(FW_MAX_PIXELS == 8u, "the sketch sets 8 pixels");\n')
    objs = []
    for src in [*sorted(core.glob("*.c")), check]:
        obj = tmp_path / (src.stem + ".o")
        subprocess.run(["arm-none-eabi-gcc", "-std=gnu11", "-Wall", "-Wextra", "-Werror",
                        "-mcpu=cortex-m7", "-mthumb", "-mfloat-abi=hard", "-mfpu=fpv5-d16",
                        "-Os", "-I", str(core), "-c", str(src), "-o", str(obj)], check=True)
        objs.append(obj)
    assert len(objs) == len(list(core.glob("*.c"))) + 1
