"""Taichi on a machine without libX11, made for real for a child process (the system's
libX11, where it has one, covered by /dev/null in a mount namespace, :mod:`no_gpu`): Taichi's
wheel links libX11 for its window, so without it Taichi cannot be imported. With the venv's
stand-in (``sim/no_display.c``, built as the Makefile builds it) the renderer runs; without one
the error names the fix."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from no_gpu import hiding_prefix

ROOT = Path(__file__).resolve().parents[2]

#: the child: grassd's backend with ``sys.prefix`` at a venv-like folder (argv[1]), one kernel
CHILD = """
import sys
sys.prefix = sys.argv[1]
from grassd.sim import backend
backend.init("cpu")
ti = backend.ti
x = ti.field(ti.f32, shape=4)

@ti.kernel
def fill():
    for i in x:
        x[i] = i * 2.0

fill()
print("sum", x.to_numpy().sum())
"""


def _child(prefix: Path, tmp_path: Path) -> subprocess.CompletedProcess:
    hide = hiding_prefix(["libX11.so"])  # [] where this machine has no libX11 to hide
    script = tmp_path / "child.py"  # a file: Taichi reads a kernel's source
    script.write_text(CHILD)
    return subprocess.run([*hide, sys.executable, str(script), str(prefix)], cwd=tmp_path,
                          capture_output=True, text=True, timeout=300,
                          env={"PATH": "/usr/bin:/bin", "HOME": str(tmp_path),
                               "GRASSD_CACHE_DIR": str(tmp_path / "cache")})


def test_the_renderer_runs_with_the_stand_in(tmp_path):
    cc = shutil.which("cc")
    if cc is None:
        pytest.skip("no C compiler (cc) to build sim/no_display.c")
    lib = tmp_path / "venv" / "lib" / "grassd"
    lib.mkdir(parents=True)
    subprocess.run([cc, "-std=c11", "-shared", "-fPIC", "-O2", "-Wall", "-Wextra", "-Werror",
                    "-Wl,-soname,libX11.so.6", "-o", str(lib / "libX11.so.6"),
                    str(ROOT / "sim" / "no_display.c")], check=True)
    r = _child(tmp_path / "venv", tmp_path)
    assert r.returncode == 0, r.stderr[-2000:]
    assert "sum 12.0" in r.stdout
    assert "import failed" not in r.stdout + r.stderr  # no failed first try shows


def test_without_a_stand_in_the_error_names_the_fix(tmp_path):
    r = _child(tmp_path / "bare-venv", tmp_path)
    assert r.returncode != 0
    assert "RendererMissing" in r.stderr and "libX11" in r.stderr, r.stderr[-2000:]
    assert "apt-get install libx11-6" in r.stderr and "make setup" in r.stderr
