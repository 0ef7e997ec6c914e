"""A truncated OpenEXR makes the OpenEXR library print lines of its own (C core on stderr:
``EXR_ERR_BAD_CHUNK_LEADER ...``; Python binding on stdout: ``Warning: Exception raised ...``).
grassd captures them around its one reading function (sim.hdri via sim.native_output): the
user sees only grassd's one-line error, which carries the library's reason (the daemon's case:
tests/daemon/runtime/test_truncated_sky_rejected.py). Output of other threads in that window is
passed through, not lost."""

from __future__ import annotations

import os
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from grassd.sim.errors import HdriError
from grassd.sim.hdri import default_site_hdri, load_hdri
from grassd.sim.native_output import capture_native_output

SITE = default_site_hdri()


def _cut(tmp_path: Path, fraction: float) -> Path:
    data = SITE.read_bytes()
    path = tmp_path / f"cut{fraction}.exr"
    path.write_bytes(data[: int(len(data) * fraction)])
    return path


@pytest.mark.parametrize("fraction", [0.01, 0.5, 0.9])
def test_simulate_cli_prints_only_our_line(tmp_path, fraction):
    cut = _cut(tmp_path, fraction)
    proc = subprocess.run(
        [sys.executable, "-m", "grassd.daemon.cli", "simulate",
         "--hdri", str(cut), "--lux", "1000", "--view", "170,2,0", "--samples", "16",
         "--lengths", "0:2:1"],
        capture_output=True, text=True, timeout=120, cwd=tmp_path,
        env={**os.environ, "PYTHONWARNINGS": "ignore"})
    assert proc.returncode == 2, proc.stderr
    assert proc.stdout == ""
    lines = proc.stderr.splitlines()
    assert len(lines) == 1, proc.stderr
    assert lines[0].startswith(f"grassd: error: {cut}: corrupt or truncated OpenEXR pixel data")
    assert "EXR_ERR_BAD_CHUNK_LEADER: " in lines[0]  # the library's reason, in our line


def test_load_hdri_leaves_nothing_on_the_descriptors(tmp_path, capfd):
    with pytest.raises(HdriError, match="EXR_ERR_BAD_CHUNK_LEADER") as info:
        load_hdri(_cut(tmp_path, 0.5))
    assert "\n" not in str(info.value)
    out, err = capfd.readouterr()
    assert out == "" and err == ""
    load_hdri(SITE)  # a good file still reads
    assert capfd.readouterr() == ("", "")


def test_other_threads_output_in_the_window_is_passed_through(capfd):
    started, release = threading.Event(), threading.Event()

    def other() -> None:
        started.wait(5)
        os.write(2, b"log line of another thread\n")
        os.write(1, b"progress of another thread\n")
        release.set()

    t = threading.Thread(target=other)
    t.start()
    with capture_native_output() as native:
        os.write(2, b"/x.exr: (EXR_ERR_CORRUPT_CHUNK) bad chunk\n")
        started.set()
        release.wait(5)
    t.join()
    out, err = capfd.readouterr()
    assert out == "progress of another thread\n"
    assert err == "log line of another thread\n"
    assert native.reason("/x.exr") == "EXR_ERR_CORRUPT_CHUNK: bad chunk"
