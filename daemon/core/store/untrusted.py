"""Reading files that someone else wrote (the inbox), as an attacker could have made them.

Every file is opened with ``O_NOFOLLOW | O_NONBLOCK`` and checked with ``fstat`` on the open
descriptor before one byte is read: a symbolic link, a FIFO (whose ``open`` would block the
main loop for ever), a device (``/dev/zero`` reads without end), a socket or a directory is
refused, and so is a regular file with a second name (a hard link: its content belongs to
someone else too) or one larger than the caller's cap. Reads stop at the cap even when the file
grows while it is read. Refusals are :class:`UntrustedFileError` (an :class:`IngestError`), whose
message names the file and says what to upload instead. A directory is walked without following
a link, up to a cap of entries (:func:`walk_entries`), and judged whole (:func:`check_entries`).
"""

from __future__ import annotations

import errno
import hashlib
import os
import stat
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

from grassd.daemon.core.config.limits import BundleLimits
from grassd.daemon.core.errors import IngestError

_OPEN_FLAGS = os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0)
_CHUNK = 1 << 20


class UntrustedFileError(IngestError):
    """A file of a bundle that the daemon will not read (its kind, links or size)."""


def kind_of(mode: int) -> str:
    """What a ``st_mode`` is, in words ('a symbolic link', 'a FIFO', ...)."""
    for test, words in ((stat.S_ISLNK, "a symbolic link"), (stat.S_ISFIFO, "a FIFO"),
                        (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
                        (stat.S_ISSOCK, "a socket"), (stat.S_ISDIR, "a directory"),
                        (stat.S_ISREG, "a regular file")):
        if test(mode):
            return words
    return "not a regular file"


def check_regular(st: os.stat_result, name: str, max_bytes: int) -> None:
    """Refuse what ``st`` (an ``lstat`` or ``fstat`` of ``name``) describes unless it is a
    regular file with one name and at most ``max_bytes`` bytes (UntrustedFileError)."""
    if not stat.S_ISREG(st.st_mode):
        raise UntrustedFileError(f"{name} is {kind_of(st.st_mode)}, not a regular file: "
                                 "upload the file itself")
    if st.st_nlink != 1:
        raise UntrustedFileError(f"{name} is a hard link ({st.st_nlink} names share it): "
                                 "upload a copy of the file")
    if st.st_size > max_bytes:
        raise UntrustedFileError(f"{name} has {st.st_size} bytes, over the cap of {max_bytes} "
                                 "([light.limits] in the configuration)")


def open_regular(path: Path, max_bytes: int) -> int:
    """An open descriptor (read-only) of ``path`` after :func:`check_regular` of its ``fstat``;
    the caller closes it. Never blocks and never follows a link in the last component."""
    try:
        fd = os.open(path, _OPEN_FLAGS)
    except OSError as exc:
        if exc.errno in (errno.ELOOP, errno.EMLINK):  # O_NOFOLLOW on a link
            raise UntrustedFileError(f"{path.name} is a symbolic link, not a regular file: "
                                     "upload the file itself") from None
        if exc.errno == errno.ENXIO:  # O_NONBLOCK on a FIFO or socket without a peer
            raise UntrustedFileError(f"{path.name} is a FIFO or socket, not a regular file: "
                                     "upload the file itself") from None
        raise
    try:
        check_regular(os.fstat(fd), path.name, max_bytes)
    except BaseException:
        os.close(fd)
        raise
    return fd


def read_regular(path: Path, max_bytes: int) -> bytes:
    """The content of regular file ``path`` (at most ``max_bytes``; see :func:`open_regular`)."""
    fd = open_regular(path, max_bytes)
    try:
        data = bytearray()
        while len(data) <= max_bytes and (block := os.read(fd, min(_CHUNK, max_bytes + 1
                                                                    - len(data)))):
            data += block
    finally:
        os.close(fd)
    if len(data) > max_bytes:  # it grew after fstat
        raise UntrustedFileError(f"{path.name} grew past the cap of {max_bytes} bytes while "
                                 "it was read ([light.limits] in the configuration)")
    return bytes(data)


#: A file as it was opened: (st_dev, st_ino, st_size, st_mtime_ns) of its descriptor
FileIdentity = tuple[int, int, int, int]


def file_identity(st: os.stat_result) -> FileIdentity:
    """The :data:`FileIdentity` of ``st``: the same file, not rewritten, while it holds (a
    rename keeps it; writing changes the size or the modification time)."""
    return (st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns)


@dataclass(frozen=True)
class HashedFile:
    """A regular file read once: its hex SHA-256 and its identity when it was opened."""

    sha256: str
    identity: FileIdentity


def hash_regular(path: Path, max_bytes: int,
                 inspect: Callable[[BinaryIO], None] | None = None) -> HashedFile:
    """Hash regular file ``path``, read up to ``max_bytes`` (:func:`open_regular`), and then
    hand the same open file to ``inspect`` (binary, seekable), so a check of its content (a
    header) reads what was hashed without opening the file again."""
    fd = open_regular(path, max_bytes)
    h = hashlib.sha256()
    n = 0
    try:
        identity = file_identity(os.fstat(fd))
        while n <= max_bytes and (block := os.read(fd, _CHUNK)):
            h.update(block)
            n += len(block)
        if n <= max_bytes and inspect is not None:
            with os.fdopen(fd, "rb", closefd=False) as fh:
                inspect(fh)
    finally:
        os.close(fd)
    if n > max_bytes:
        raise UntrustedFileError(f"{path.name} grew past the cap of {max_bytes} bytes while "
                                 "it was read ([light.limits] in the configuration)")
    return HashedFile(h.hexdigest(), identity)


def sha256_regular(path: Path, max_bytes: int) -> str:
    """Hex SHA-256 of regular file ``path``, read up to ``max_bytes`` (:func:`open_regular`)."""
    return hash_regular(path, max_bytes).sha256


def walk_entries(members: list[Path], cap: int) -> list[tuple[Path, os.stat_result]]:
    """(path, lstat) of ``members`` and, for a directory, everything below it, never following
    a link; stops after ``cap`` + 1 entries. Entries that vanish meanwhile are left out."""
    out: list[tuple[Path, os.stat_result]] = []
    todo = list(reversed(members))
    while todo and len(out) <= cap:
        p = todo.pop()
        try:
            st = p.lstat()
        except OSError:
            continue
        if p not in members:
            out.append((p, st))
        elif not stat.S_ISDIR(st.st_mode):
            out.append((p, st))
        if stat.S_ISDIR(st.st_mode):
            try:
                with os.scandir(p) as it:
                    todo.extend(sorted((Path(e.path) for e in it), reverse=True))
            except OSError:
                continue
    return out


def check_entries(entries: list[tuple[Path, os.stat_result]], base: Path,
                  limits: BundleLimits) -> None:
    """Refuse a bundle whose entries (:func:`walk_entries`) break ``limits`` (entries; bytes
    per file and in all) or are not regular files or directories (UntrustedFileError naming
    the first such entry relative to ``base``)."""
    if len(entries) > limits.entries:
        raise UntrustedFileError(f"bundle holds more than {limits.entries} files and folders "
                                 "([light.limits] entries in the configuration)")
    total = 0
    for p, st in entries:
        if stat.S_ISDIR(st.st_mode):
            continue
        name = str(p.relative_to(base)) if p.is_relative_to(base) else p.name
        check_regular(st, name, limits.file_bytes)
        total += st.st_size
    if total > limits.bundle_bytes:
        raise UntrustedFileError(f"bundle holds {total} bytes, over the cap of "
                                 f"{limits.bundle_bytes} ([light.limits] bundle_mib in the "
                                 "configuration)")
