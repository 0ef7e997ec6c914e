"""The host side of a simulated serial line, shared by :class:`~.simulator.SimulatedBus` and
:class:`~.qemu_bus.QemuBus`: a raw pseudo-terminal behind an optional stable symlink (as
udev's /dev/serial/by-id links), and pacing of the bytes at a baud rate (8N1: 10 bit times
per byte)."""

from __future__ import annotations

import os
import time
import tty
from pathlib import Path

from grassd.firmware_proto.errors import SimulatorError


def open_raw_pty(link_path: Path | None) -> tuple[int, int, str]:
    """Open a pty, slave in raw mode and master non-blocking; point ``link_path`` (if any) at
    it by an atomic rename of a fresh symlink. Returns (master fd, slave fd, slave device).
    Raises :class:`SimulatorError` when no pty can be made."""
    try:
        master, slave = os.openpty()
    except OSError as exc:
        raise SimulatorError(f"cannot create a pseudo-terminal: {exc}") from None
    try:
        tty.setraw(slave)
        os.set_blocking(master, False)
        device = os.ttyname(slave)
        if link_path is not None:
            tmp = link_path.with_name(link_path.name + ".new")
            tmp.unlink(missing_ok=True)
            tmp.symlink_to(device)
            os.replace(tmp, link_path)
    except OSError as exc:
        close_fds(master, slave)
        raise SimulatorError(f"cannot set up the pseudo-terminal: {exc}") from None
    return master, slave, device


def close_fds(*fds: int) -> None:
    """Close every fd that is open (>= 0), ignoring one already gone."""
    for fd in fds:
        if fd >= 0:
            try:
                os.close(fd)
            except OSError:
                pass


class LinePacer:
    """Holds the calling thread while bytes cross a line of ``baud`` bit/s (None or 0: no
    pacing), as a UART sends them: 10 bit times per byte (8N1), back to back."""

    def __init__(self, baud: int | None) -> None:
        self.baud = baud
        self._line_free = 0.0  # time.monotonic() at which the line is idle again

    def pace(self, n_bytes: int) -> None:
        """Return once ``n_bytes`` more have crossed the line (after those before them)."""
        if not self.baud:
            return
        now = time.monotonic()
        self._line_free = max(now, self._line_free) + n_bytes * 10 / self.baud
        if self._line_free > now:
            time.sleep(self._line_free - now)
