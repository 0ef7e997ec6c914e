"""Atomic file writes: write a temporary file in the target directory, fsync it, rename it over
the target, fsync the directory. A crash leaves either the old file or the new one, never a
truncated mix (POSIX rename(2) atomicity within one file system)."""

from __future__ import annotations

import contextlib
import errno
import json
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any

if TYPE_CHECKING:
    from matplotlib.figure import Figure


def fsync_dir(path: str | os.PathLike[str]) -> None:
    """fsync a directory so that a rename or create inside it survives a power cut."""
    fd = os.open(path, os.O_RDONLY | os.O_DIRECTORY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def fsync_file(path: str | os.PathLike[str]) -> None:
    """fsync a file written by other code (e.g. a library that only takes a file name), so
    that its data is on disk before a rename makes it visible."""
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


@contextlib.contextmanager
def atomic_open(path: str | os.PathLike[str], mode: int = 0o644) -> Iterator[IO[bytes]]:
    """Context manager yielding a binary file; on clean exit it atomically replaces ``path``.

    On an exception the temporary file is removed and ``path`` is left untouched.
    """
    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent)
    try:
        with os.fdopen(fd, "wb") as fh:
            yield fh
            fh.flush()
            os.fsync(fh.fileno())
        os.chmod(tmp, mode)
        os.replace(tmp, target)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise
    fsync_dir(target.parent)


def atomic_write_bytes(path: str | os.PathLike[str], data: bytes, mode: int = 0o644) -> Path:
    """Atomically write ``data`` to ``path``; returns the path."""
    with atomic_open(path, mode) as fh:
        fh.write(data)
    return Path(path)


def atomic_write_text(path: str | os.PathLike[str], text: str, mode: int = 0o644) -> Path:
    """Atomically write UTF-8 ``text`` to ``path``."""
    return atomic_write_bytes(path, text.encode("utf-8"), mode)


def atomic_write_json(path: str | os.PathLike[str], obj: Any, mode: int = 0o644) -> Path:
    """Atomically write ``obj`` as indented JSON (NaN/Inf refused: reports must be valid JSON)."""
    text = json.dumps(obj, indent=2, sort_keys=True, allow_nan=False, default=_json_default)
    return atomic_write_text(path, text + "\n", mode)


def atomic_save_figure(path: str | os.PathLike[str], figure: Figure) -> Path:
    """Atomically save a matplotlib ``figure`` as PNG to ``path``."""
    with atomic_open(path) as fh:
        figure.savefig(fh, format="png")
    return Path(path)


#: What the user must do about a failed write, by errno.
_WRITE_FIXES = {
    errno.ENOSPC: "the file system is full: free space on it",
    errno.EDQUOT: "the disk quota is exhausted: free space or raise the quota",
    errno.EROFS: "the file system is mounted read-only: remount it read-write",
    errno.EACCES: "permission denied: give the daemon's user write access to it",
    errno.EPERM: "operation not permitted: give the daemon's user write access to it",
    errno.EFBIG: "the file would exceed the size limit (RLIMIT_FSIZE / LimitFSIZE=)",
    errno.EIO: "I/O error: check the disk (dmesg)",
}


#: What the user must do about a failed read (or directory scan), by errno.
_READ_FIXES = {
    errno.ENOENT: "it does not exist (a share or mount that went away?): create or mount it",
    errno.ENOTDIR: "a part of the path is not a directory: fix the path",
    errno.ELOOP: "too many symbolic links: fix the link",
    errno.ESTALE: "stale file handle (NFS): remount the share",
    errno.EACCES: "permission denied: give the daemon's user read access to it",
    errno.EPERM: "operation not permitted: give the daemon's user read access to it",
    errno.EIO: "I/O error: check the disk or the share (dmesg)",
}


#: errno values that only a write can meet
WRITE_ONLY_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EFBIG})

#: Fixes when it is not known whether a read or a write failed.
_ACCESS_FIXES = {
    **_READ_FIXES, **_WRITE_FIXES,
    errno.EACCES: "permission denied: give the daemon's user read and write access to it",
    errno.EPERM: "operation not permitted: give the daemon's user read and write access to it",
}


def describe_os_error(exc: OSError, where: str | os.PathLike[str], action: str = "write") -> str:
    """One line naming what could not be read or written (``where``), why, and the fix.

    ``action`` is "read" (reading or scanning ``where``), "write", or "access" when it is not
    known which; errors that only a write can meet (full disk, quota, read-only file system,
    file size limit) are worded as a write whatever ``action`` says.

    >>> import errno
    >>> print(describe_os_error(OSError(errno.ELOOP, "Too many links"), "/in", "read"))
    cannot read /in: Too many links (ELOOP): too many symbolic links: fix the link
    """
    if action not in ("read", "write", "access"):
        raise ValueError(f"action must be 'read', 'write' or 'access', not {action!r}")
    if exc.errno in WRITE_ONLY_ERRNOS:
        action = "write"
    name = errno.errorcode.get(exc.errno or 0, "")
    why = exc.strerror or str(exc)
    fixes = {"write": _WRITE_FIXES, "read": _READ_FIXES, "access": _ACCESS_FIXES}[action]
    fix = fixes.get(exc.errno or 0)
    return (f"cannot {action} {'to ' if action == 'write' else ''}{os.fspath(where)}: {why}"
            + (f" ({name})" if name else "") + (f": {fix}" if fix else ""))


def describe_write_error(exc: OSError, where: str | os.PathLike[str]) -> str:
    """One line naming what could not be written (``where``), why, and the fix.

    >>> import errno
    >>> print(describe_write_error(OSError(errno.ENOSPC, "No space left on device"), "/s"))
    cannot write to /s: No space left on device (ENOSPC): the file system is full: free space on it
    """
    return describe_os_error(exc, where, "write")


def _json_default(obj: Any) -> Any:
    if isinstance(obj, os.PathLike):
        return os.fspath(obj)
    tolist = getattr(obj, "tolist", None)
    if callable(tolist):  # numpy arrays and scalars
        return tolist()
    raise TypeError(f"cannot write {type(obj).__name__} as JSON")
