"""Whether a path can be changed by no one but this process's user (and root), as ssh asks of
``~/.ssh``: what is read from it is then this user's own.

The path itself must belong to the user and let neither its group nor others write it. Every
directory above it, up to ``/``, must belong to root or the user and let neither group nor
others write it, unless it has the sticky bit (``/tmp``: others may add entries there, but
neither move nor replace this user's). Symbolic links on the way are followed, and the
directories of their targets are held to the same rule.
"""

from __future__ import annotations

import os
import pwd
import stat
from dataclasses import dataclass
from pathlib import Path

__all__ = ["Untrusted", "untrusted_part", "untrusted_below", "owner_name"]


@dataclass(frozen=True)
class Untrusted:
    """Why ``path`` (the part of the checked path at fault) may be changed by another user:
    ``reason`` says whose it is or who may write it."""

    path: Path
    reason: str

    def __str__(self) -> str:
        return f"{self.path} {self.reason}"


def owner_name(uid: int) -> str:
    """``uid`` with its account's name, e.g. ``"uid 65534 (nobody)"``."""
    try:
        return f"uid {uid} ({pwd.getpwuid(uid).pw_name})"
    except KeyError:
        return f"uid {uid} (no account)"


def _problem(path: Path, st: os.stat_result, uid: int, leaf: bool) -> Untrusted | None:
    owners = (uid,) if leaf else (0, uid)
    if st.st_uid not in owners:
        return Untrusted(path, f"belongs to {owner_name(st.st_uid)}, not to "
                               f"{owner_name(uid)}" + ("" if leaf or uid == 0 else " or root"))
    if stat.S_ISLNK(st.st_mode):
        return None  # a link's own mode means nothing; its target is checked on its own
    sticky_dir = stat.S_ISDIR(st.st_mode) and st.st_mode & stat.S_ISVTX
    if st.st_mode & (stat.S_IWGRP | stat.S_IWOTH) and (leaf or not sticky_dir):
        who = "every user" if st.st_mode & stat.S_IWOTH else "its group"
        return Untrusted(path, f"is writable by {who} (mode {stat.S_IMODE(st.st_mode):04o})")
    return None


def _walk(path: Path, uid: int) -> Untrusted | None:
    """The first fault on ``path`` (absolute) and each directory above it, by ``lstat``."""
    for i, part in enumerate([path, *path.parents]):
        try:
            st = os.lstat(part)
        except FileNotFoundError:
            continue  # checked again once it exists
        if (found := _problem(part, st, uid, leaf=i == 0)) is not None:
            return found
    return None


def untrusted_part(path: Path | str, uid: int | None = None) -> Untrusted | None:
    """None where ``path`` and every directory above it can be changed only by user ``uid``
    (default: this process's effective uid) and root; else the first part at fault. A part
    that does not exist yet is skipped."""
    uid = os.geteuid() if uid is None else uid
    lexical = Path(os.path.abspath(path))
    return _walk(lexical, uid) or _walk(Path(os.path.realpath(lexical)), uid)



def untrusted_below(root: Path | str, uid: int,
                    skip: frozenset[Path] = frozenset()) -> Untrusted | None:
    """The first entry below the directory ``root`` (whose own path :func:`untrusted_part`
    checks) that is not user ``uid``'s alone: another user's, or writable by its group or
    others. Entries in ``skip`` and what lies below them, and sockets (whose peers are checked
    where they are served), are left out; links are not followed."""
    skipped = {str(p) for p in skip}
    stack = [str(root)]
    while stack:
        try:
            entries = os.scandir(stack.pop())
        except (FileNotFoundError, NotADirectoryError):  # gone meanwhile
            continue
        with entries:
            for entry in entries:
                if entry.path in skipped:
                    continue
                try:
                    st = entry.stat(follow_symlinks=False)
                except FileNotFoundError:
                    continue
                if stat.S_ISSOCK(st.st_mode):
                    continue
                if (fault := _problem(Path(entry.path), st, uid, leaf=True)) is not None:
                    return fault
                if stat.S_ISDIR(st.st_mode):
                    stack.append(entry.path)
    return None
