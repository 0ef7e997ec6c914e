"""Which firmware answers on a simulated bus: the Python model or a build of the C firmware.

* ``model``: :class:`~.simulator.SimulatedBus` with :class:`~.firmware.Controller` objects in
  this process (fault injection, echo).
* ``posix``: :class:`~.posix_bus.PosixBus`, the C core in a Linux process (``firmware/``).
* ``qemu``: :class:`~.qemu_bus.QemuBus`, the Cortex-M7 image under ``qemu-system-arm``.

Every bus has ``path``, ``device``, ``controllers`` (each with ``config`` and
``active_table()``), ``start``/``stop`` and context management, so host code and tests take
any of them.
"""

from __future__ import annotations

import tempfile
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from grassd.firmware_proto.errors import SimulatorError
from grassd.rigs import FIRMWARE_BACKENDS
from grassd.rigs.firmware import ControllerConfig, bus_pixels, simulated_config


def open_bus(firmware: str, state_dir: str | Path, addresses: Sequence[int], *,
             n_pixels: int | Sequence[int] = ControllerConfig.n_pixels,
             link_path: str | Path | None = None,
             baud: int | None = None) -> Any:
    """A bus (not yet started) of controllers at ``addresses`` running ``firmware``; their
    storage lives in ``state_dir`` (reused, so tables survive a restart). ``n_pixels``: per
    controller, one value or one per address. ``baud``: pace the line (None: unpaced)."""
    state_dir = Path(state_dir)
    if firmware not in FIRMWARE_BACKENDS:
        raise SimulatorError(f"unknown firmware {firmware!r}; choose one of "
                             f"{', '.join(FIRMWARE_BACKENDS)}")
    pixels = bus_pixels("a simulated bus", addresses, n_pixels)
    if firmware == "model":
        from grassd.rigs.firmware import Controller
        from grassd.rigs.simulator import SimulatedBus

        ctrls = [Controller(simulated_config(a, n_pixels=p), state_dir / f"controller-{a}.eeprom")
                 for a, p in zip(addresses, pixels, strict=True)]
        return SimulatedBus(ctrls, link_path=link_path, baud=baud)
    if firmware == "posix":
        from grassd.rigs.posix_bus import PosixBus

        return PosixBus(state_dir, addresses, n_pixels=pixels, link_path=link_path, baud=baud)
    from grassd.rigs.qemu_bus import QemuBus  # "qemu"

    return QemuBus(state_dir, addresses, n_pixels=pixels, link_path=link_path, baud=baud)


def start_buses(firmware: str, state_dir: str | Path, count: int, *, shared: bool = True,
                link_dir: str | Path | None = None, baud: int | None = None,
                n_pixels: int = ControllerConfig.n_pixels) -> list[Any]:
    """Start ``count`` controllers running ``firmware``: all on one bus (addresses 1..count) if
    ``shared``, else each on its own pty with address 1. Symlinks ``link_dir/bus<i>`` name the
    ports."""
    if count < 1:
        raise SimulatorError(f"need at least one controller, got {count}")
    link_dir = Path(link_dir) if link_dir is not None else Path(tempfile.mkdtemp(prefix="grassd-"))
    link_dir.mkdir(parents=True, exist_ok=True)
    state_dir = Path(state_dir)
    if shared:
        groups = [(state_dir, list(range(1, count + 1)))]
    else:
        groups = [(state_dir / f"port{i}", [1]) for i in range(count)]
    buses: list[Any] = []
    try:
        for i, (d, addrs) in enumerate(groups):
            buses.append(open_bus(firmware, d, addrs, n_pixels=n_pixels,
                                  link_path=link_dir / f"bus{i}", baud=baud).start())
    except BaseException:
        for b in buses:
            b.stop()
        raise
    return buses
