"""grassd's cache directory, one per user, and the check that makes a kernel cache this
user's own before Taichi loads it.

A cached kernel is code (LLVM IR under a plain hash): a process that loads a cache another user
may write runs that user's code. So the default is each user's own (the service's is its
systemd ``CacheDirectory``, a command run by root uses root's), and a cache that belongs to
another user, or that its group or others may write (it, or a directory above it:
:mod:`grassd.sim.path_trust`), is ignored with a warning and a private one is used instead.

The default is written here only; the configuration's ``cache_dir`` falls back to it.
"""

from __future__ import annotations

import logging
import os
from pathlib import Path

from grassd.sim.path_trust import untrusted_part

__all__ = ["default_cache_dir", "user_cache_dir", "trusted_kernel_dir", "KERNELS"]

#: The subdirectory of grassd's cache directory that holds Taichi's kernels.
KERNELS = "taichi"

log = logging.getLogger(__name__)


def user_cache_dir() -> Path:
    """This user's own grassd cache: ``$XDG_CACHE_HOME/grassd``, else ``~/.cache/grassd``."""
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "grassd"


def default_cache_dir() -> Path:
    """grassd's cache directory when the configuration names none: ``$GRASSD_CACHE_DIR``,
    systemd's ``$CACHE_DIRECTORY`` (the service's ``CacheDirectory=``), else
    :func:`user_cache_dir`. Kernels go into its :data:`KERNELS` subdirectory."""
    for var in ("GRASSD_CACHE_DIR", "CACHE_DIRECTORY"):
        if os.environ.get(var):
            return Path(os.environ[var].split(":")[0])
    return user_cache_dir()


def _usable(path: Path, inner: str) -> str | None:
    """None where ``path`` (created, mode 0700, if missing) and its ``inner`` subdirectory
    (where it exists) are this user's alone; else why not."""
    try:
        path.mkdir(parents=True, exist_ok=True, mode=0o700)
    except OSError as exc:
        return f"cannot be created ({exc.strerror})"
    for part in (path, path / inner):
        if part.exists() and (fault := untrusted_part(part)) is not None:
            return str(fault)
    return None


def _private_dir() -> Path:
    """A fresh kernel directory of this process's own, removed when it exits."""
    import atexit
    import shutil
    import tempfile  # here: the configuration imports this module, light commands too

    path = Path(tempfile.mkdtemp(prefix="grassd-kernels-"))
    atexit.register(shutil.rmtree, path, ignore_errors=True)
    return path


def trusted_kernel_dir(wanted: Path, inner: str) -> Path:
    """``wanted`` (a kernel directory; Taichi's files go into its ``inner`` subdirectory) where
    it is this user's alone. Otherwise a warning, and this user's own kernel directory
    (:func:`user_cache_dir`) if that one is, else a private one removed at exit."""
    problem = _usable(wanted, inner)
    if problem is None:
        return wanted
    own = user_cache_dir() / KERNELS
    fallback = own if own != wanted and _usable(own, inner) is None else _private_dir()
    log.warning("kernel cache %s ignored: %s; a cached kernel is code, so only this user "
                "(uid %d) may write its cache. Using %s instead; chown or chmod it, or set "
                "GRASSD_CACHE_DIR to a directory of this user's", wanted, problem,
                os.geteuid(), fallback)
    return fallback
