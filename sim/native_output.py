"""Capture what a C/C++ library prints to file descriptors 1 and 2 while it runs.

OpenEXR's C core reports a damaged file on stderr (``file: (EXR_ERR_BAD_CHUNK_LEADER) ...``)
and its Python binding prints ``Warning: Exception raised reading pixel data ...`` on stdout,
before raising an exception that grassd turns into its own one-line error. Python's
``contextlib.redirect_stderr`` cannot catch that: it only swaps ``sys.stderr``. So
:func:`capture_native_output` points fds 1 and 2 at temporary files with ``dup2`` for the
duration of the call, flushes C stdio before restoring them, and hands back the library's lines
(for the error message), so the user sees grassd's line only. ``sys.stdout`` / ``sys.stderr``
are swapped for buffers too, since the binding writes through them and they need not be fds
1 and 2 (under a test runner, for instance).

Thread safety: one call at a time (a module lock). Output that *other* threads write to fd 1
or 2 (or sys.stdout / sys.stderr) in that window (daemon log lines, progress) is not lost:
every captured line that does not look like the library's (:data:`NATIVE_MARKERS`) is written
back where it was going after the call, only delayed by the length of the read.
"""

from __future__ import annotations

import contextlib
import ctypes
import io
import os
import sys
import tempfile
import threading
from collections.abc import Iterator
from dataclasses import dataclass, field

#: Substrings of the lines OpenEXR (C core and Python binding) prints about a damaged file.
NATIVE_MARKERS = ("EXR_ERR_", "Warning: Exception raised reading")

_LOCK = threading.Lock()
try:
    _LIBC = ctypes.CDLL(None)
except OSError:  # pragma: no cover - every Linux process has a C library
    _LIBC = None


@dataclass
class NativeOutput:
    """The library's lines captured by :func:`capture_native_output` (filled when it ends)."""

    lines: list[str] = field(default_factory=list)

    def reason(self, path: str) -> str | None:
        """The library's last EXR_ERR line as ``CODE: text``, without the ``path: (CODE)``
        framing it adds, or None when it said nothing of the kind."""
        errs = [ln for ln in self.lines if "EXR_ERR_" in ln]
        if not errs:
            return None
        text = errs[-1].removeprefix(f"{path}: ").strip()
        if text.startswith("(") and ")" in text:
            code, rest = text[1:].split(")", 1)
            text = f"{code}: {rest.strip()}"
        return text


def _flush_all() -> None:
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):
            stream.flush()
    if _LIBC is not None:
        _LIBC.fflush(None)  # C stdio buffers (std::cout/cerr are synced with them)


@contextlib.contextmanager
def capture_native_output() -> Iterator[NativeOutput]:
    """Run the body with fds 1 and 2 captured; the yielded :class:`NativeOutput` holds the
    library's lines once the body is done (other lines go back to their descriptor)."""
    out = NativeOutput()
    with _LOCK:
        _flush_all()
        saved: dict[int, int] = {}
        for fd in (1, 2):
            with contextlib.suppress(OSError):  # a closed descriptor is left alone
                saved[fd] = os.dup(fd)
        files = {fd: tempfile.TemporaryFile() for fd in saved}
        # the binding writes through sys.stdout (PySys_WriteStdout), which need not be fd 1
        streams = {"stdout": sys.stdout, "stderr": sys.stderr}
        buffers = {name: io.StringIO() for name in streams}
        try:
            for fd, f in files.items():
                os.dup2(f.fileno(), fd)
            sys.stdout, sys.stderr = buffers["stdout"], buffers["stderr"]
            try:
                yield out
            finally:
                sys.stdout, sys.stderr = streams["stdout"], streams["stderr"]
                _flush_all()
                for fd, orig in saved.items():
                    os.dup2(orig, fd)
        finally:
            for fd, f in files.items():
                os.close(saved[fd])
                f.seek(0)
                others = _sort_lines(f.read().decode("utf-8", "replace"), out)
                f.close()
                if others:
                    with contextlib.suppress(OSError):
                        os.write(fd, others.encode())
            for name, buf in buffers.items():
                if others := _sort_lines(buf.getvalue(), out):
                    with contextlib.suppress(Exception):
                        streams[name].write(others)
                        streams[name].flush()


def _sort_lines(text: str, out: NativeOutput) -> str:
    """Append the library's lines of ``text`` to ``out``; return the other lines."""
    others = []
    for line in text.splitlines(keepends=True):
        if any(m in line for m in NATIVE_MARKERS):
            out.lines.append(line.rstrip("\n"))
        else:
            others.append(line)
    return "".join(others)
