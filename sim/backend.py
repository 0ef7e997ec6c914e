"""The one module that imports Taichi. Everything else in grassd reaches Taichi through here.

Where Taichi is missing (no wheels for Linux aarch64; a plain ``pip install grassd`` there
leaves it out, ``grassd[sim]`` asks for it) importing this module raises
:class:`~grassd.sim.errors.RendererMissing`, a one-line :class:`SimError` that every command
needing the renderer shows as it is.

Taichi 1.7.4 is the last upstream release; keeping the import behind this module makes a move
to a maintained fork a one-file change. :func:`init` is called once by the program's entry point
(the CLI, the daemon, a benchmark, a test fixture), never at import time.
"""

from __future__ import annotations

import contextlib
import hashlib
import logging
import os
import sys
from pathlib import Path

os.environ.setdefault("ENABLE_TAICHI_HEADER_PRINT", "False")  # keep stdout clean for JSON

from grassd.sim import kernel_cache
from grassd.sim.errors import SimError, renderer_missing
from grassd.sim.gpu_devices import (
    VulkanDevice,
    cuda_device_count,
    vulkan_devices,
)

#: Where the Makefile puts the library that answers Taichi's window calls on a machine
#: without libX11 (``sim/no_display.c``): in the venv, beside the interpreter's own lib/.
NO_DISPLAY_LIB = Path(sys.prefix) / "lib" / "grassd" / "libX11.so.6"


def _import_taichi():
    """Taichi, imported. The wheel links libX11.so.6 for a window grassd never opens: where
    the venv holds :data:`NO_DISPLAY_LIB` (the Makefile builds it on a machine without
    libX11) and the system's libX11 cannot be loaded, that library is loaded first, so the
    loader finds a libX11 already there. RendererMissing when Taichi cannot be imported."""
    if NO_DISPLAY_LIB.is_file():
        import ctypes

        try:
            ctypes.CDLL("libX11.so.6")
        except OSError:
            ctypes.CDLL(str(NO_DISPLAY_LIB), mode=os.RTLD_NOW | os.RTLD_GLOBAL)
    try:
        import taichi
    except ImportError as exc:  # e.g. Linux aarch64: Taichi publishes no wheels for it
        raise renderer_missing(str(exc)) from None
    return taichi


ti = _import_taichi()

__all__ = ["ti", "init", "is_initialised", "default_cache_dir"]

_state: dict[str, str] = {}
log = logging.getLogger(__name__)


def default_cache_dir() -> Path:
    """Where compiled kernels are cached when :func:`init` is given no directory: the
    :data:`~grassd.sim.kernel_cache.KERNELS` subdirectory of
    :func:`grassd.sim.kernel_cache.default_cache_dir` (this user's own)."""
    return kernel_cache.default_cache_dir() / kernel_cache.KERNELS


#: Taichi's compile options, every kernel alike.
#:
#: * ``cfg_optimization=False`` skips Taichi's control-flow-graph IR passes: the path-tracing
#:   kernel compiles in 1.5 s instead of 6.5 s on 2 cores and runs as fast (2.64-2.77 vs
#:   2.74-2.82 CPU-us per path, measured twice each); LLVM still optimises the code.
#: * ``make_cpu_multithreading_loop=False`` and ``cpu_block_dim_adaptive=False``: a parallel
#:   loop on the CPU goes in tasks of Taichi's default 32 iterations, taken by the threads as
#:   they free up. Taichi's own scheme cuts a loop into one block per thread of at least 512
#:   iterations, so a launch of 512 camera paths or fewer ran on one core (a splayed launch of
#:   2 replicates of 256 paths took 28 ms with 1 thread or 2; 14 ms now), and a launch of
#:   1024 on two blocks, one core idle while the other finished its half. Measured (the
#:   studio's splayed characteristic to 0.1 dE00, six viewpoints, 2 cores, in process): the
#:   same CPU time (1.6-1.8 s), 1.5-1.6 cores busy before and 1.7-1.9 after, median 1.06-1.13 s
#:   before and 0.86-1.05 s after; the daemon's launches (131072 paths) and the pixel's images
#:   take the time they took.
COMPILE_OPTIONS: dict = dict(default_fp=ti.f32, random_seed=0, cfg_optimization=False,
                             make_cpu_multithreading_loop=False, cpu_block_dim_adaptive=False)
# Taichi's offline cache key leaves the CPU loop options out, so kernels compiled under other
# options get their own directory (a kernel cached before would otherwise keep its old tasks).
_CACHE_SUBDIR = "kernels-" + hashlib.sha256(
    repr(sorted((k, str(v)) for k, v in COMPILE_OPTIONS.items())).encode()).hexdigest()[:8]


def init(arch: str = "cpu", cache_dir: Path | None = None, threads: int | None = None) -> str:
    """Initialise Taichi once per process; later calls with the same arch are no-ops.

    ``arch`` is ``"cpu"`` (default) or ``"gpu"`` (CUDA/Vulkan/Metal, whichever Taichi finds;
    the CPU, with a warning, where there is none; a warning too where the only Vulkan device
    runs on the CPU). Returns the arch actually in use. The offline cache in ``cache_dir``
    (default :func:`default_cache_dir`; one that another user may write is ignored with a
    warning: :func:`grassd.sim.kernel_cache.trusted_kernel_dir`) makes the first call in a
    fresh process skip LLVM compilation of kernels compiled before.
    """
    if arch not in ("cpu", "gpu"):
        raise SimError(f"arch must be 'cpu' or 'gpu', got {arch!r}")
    if _state:
        if _state["arch"] != arch:
            raise SimError(f"Taichi already initialised for {_state['arch']}; one arch per process")
        return _state["actual"]
    cache = kernel_cache.trusted_kernel_dir(Path(cache_dir) if cache_dir else default_cache_dir(),
                                            _CACHE_SUBDIR)
    _remove_unkeyed_cache(cache)
    kwargs = dict(offline_cache=True, offline_cache_file_path=str(cache / _CACHE_SUBDIR),
                  log_level=ti.WARN, **COMPILE_OPTIONS)
    if threads:
        kwargs["cpu_max_num_threads"] = threads
    devices: list[VulkanDevice] = []
    target = ti.cpu
    if arch == "gpu":
        devices = vulkan_devices()
        # Taichi 1.7.4 does not fall back to the CPU by itself: without a CUDA device it goes
        # on to Vulkan and dies there where no Vulkan device is found (no loader, no driver,
        # or a driver without a device). The gpu arch is asked for only where a device is
        # (on macOS: Metal, which every Mac has).
        if sys.platform == "darwin" or cuda_device_count() or devices:
            target = ti.gpu
    with contextlib.redirect_stdout(sys.stderr):  # Taichi prints "Starting on arch=..."
        ti.init(arch=target, **kwargs)
    actual = str(ti.lang.impl.current_cfg().arch).split(".")[-1]
    _state.update(arch=arch, actual=actual)
    if arch == "gpu":
        _warn_if_on_cpu(actual, devices)
    return actual


def _warn_if_on_cpu(actual: str, devices: list[VulkanDevice]) -> None:
    """Warn where the ``gpu`` arch (Taichi arch ``actual``; the Vulkan ``devices``,
    :func:`grassd.sim.gpu_devices.vulkan_devices`) runs on this machine's CPU after all: there
    is no GPU, or the only Vulkan device is a software one (Mesa's lavapipe): measured on 2
    cores, the studio's characteristic 33x and ``bench_backend``'s trace 34x slower than the
    CPU backend."""
    if actual in ("x64", "arm64"):
        log.warning("--arch gpu: Taichi found no GPU here (neither CUDA nor a Vulkan "
                    "device): it runs on the CPU, as --arch cpu does; install the GPU's driver "
                    "to use it")
    elif actual == "vulkan":
        if devices and all(d.on_cpu for d in devices):
            log.warning("--arch gpu runs on %s, a Vulkan driver that runs on the CPU: "
                        "about 30x slower than --arch cpu; install the GPU's driver (CUDA "
                        "or Vulkan), or use --arch cpu", devices[0].name)


def _remove_unkeyed_cache(cache: Path) -> None:
    """Remove the kernels that grassd cached in ``cache`` itself before they went into a
    directory per option set (``*.tic`` files and Taichi's index ``ticache.tcb``): no process
    reads them any more, and Taichi's own clean-up (least recently used, past 100 MB) only runs
    in the directory it caches in. A file that cannot be removed is left (another user's)."""
    for path in [*cache.glob("*.tic"), cache / "ticache.tcb"]:
        with contextlib.suppress(OSError):
            path.unlink()


def runs_on_host() -> bool:
    """True when the kernels run on this machine's CPU (Taichi's x64 or arm64 backend), where a
    kernel reads a NumPy array argument in place. On a GPU a kernel reads a copy that Taichi
    makes at launch and writes back after it."""
    return _state.get("actual") in ("x64", "arm64")


def is_initialised() -> bool:
    """True once :func:`init` has run in this process."""
    return bool(_state)
