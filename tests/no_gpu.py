"""A machine without a GPU stack, made for real for a child process whatever this machine has:
the Vulkan loader (``libvulkan.so*``) and NVIDIA's CUDA driver (``libcuda.so*``), the libraries
Taichi's gpu arch and :mod:`grassd.sim.gpu_devices` open, covered by /dev/null in a mount
namespace of the child's own (``unshare --mount --map-root-user``, util-linux; no privilege
needed where user namespaces are on). A library this machine lacks needs no hiding."""

from __future__ import annotations

import glob
import os
import shlex
import shutil
import subprocess
from collections.abc import Sequence

import pytest

#: What each library is to a reader of a skip line, by its file name's stem.
LIBRARIES: dict[str, str] = {"libvulkan.so": "Vulkan loader", "libcuda.so": "CUDA driver",
                             "libX11.so": "X11 client library"}
_LIBRARY_DIRS = ("/lib", "/lib64", "/usr/lib", "/usr/lib64", "/usr/local/lib")


def library_files(stem: str) -> list[str]:
    """The files on this machine that ``stem`` (e.g. ``"libvulkan.so"``) and its versioned
    names resolve to: what ``ldconfig -p`` lists, and what the library folders (their
    multiarch subfolders too) and ``$LD_LIBRARY_PATH`` hold."""
    listed = subprocess.run(["ldconfig", "-p"], capture_output=True, text=True).stdout
    found = {line.split(" => ", 1)[1].strip() for line in listed.splitlines()
             if stem in line and " => " in line}
    extra = [d for d in os.environ.get("LD_LIBRARY_PATH", "").split(":") if d]
    for root in (*_LIBRARY_DIRS, *extra):
        for pattern in (f"{stem}*", f"*/{stem}*"):
            found.update(glob.glob(os.path.join(root, pattern)))
    return sorted({os.path.realpath(f) for f in found if os.path.exists(f)})


#: The GPU stack: what a machine without a GPU lacks.
GPU_LIBRARIES = ("libvulkan.so", "libcuda.so")


def hiding_prefix(stems: Sequence[str] = GPU_LIBRARIES) -> list[str]:
    """The argv to put before a command so that it runs with the libraries ``stems`` (keys of
    :data:`LIBRARIES`) hidden: ``[]`` where this machine has none of them. Skips the test with
    one line where they cannot be hidden (no ``unshare``, or user namespaces turned off)."""
    found = {stem: library_files(stem) for stem in stems}
    files = [f for names in found.values() for f in names]
    if not files:
        return []
    what = " and ".join(LIBRARIES[stem] for stem, names in found.items() if names)
    unshare = shutil.which("unshare")
    if unshare is None:
        pytest.skip(f"no unshare (util-linux) to hide this machine's {what}")
    hide = " && ".join(f"mount --bind /dev/null {shlex.quote(f)}" for f in files)
    probe = subprocess.run([unshare, "--mount", "--map-root-user", "sh", "-c", hide],
                           capture_output=True, text=True)
    if probe.returncode != 0:
        pytest.skip(f"cannot hide this machine's {what} in a mount namespace "
                    f"(user namespaces off?): {probe.stderr.strip()[:200]}")
    return [unshare, "--mount", "--map-root-user", "sh", "-c", hide + ' && exec "$@"', "no-gpu"]
