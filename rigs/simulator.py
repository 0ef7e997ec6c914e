"""Simulated controllers on real pseudo-terminals, so clients use pyserial exactly as on hardware.

A :class:`SimulatedBus` owns one pty (``os.openpty``, slave in raw mode) and a thread that reads
what the host writes, reassembles frames, hands them to every :class:`~.firmware.Controller` on
the bus (each answers only its own address, as on RS-485) and writes the answers back. It can
pace bytes at a baud rate (10 bit times per byte, 8N1), inject faults from a
:class:`~.faults.FaultInjector`, and *unplug*: close the pty master (pyserial then fails with
EIO, as for a USB device pulled out), remove the stable symlink, and later plug a fresh pty in
behind the same symlink (as udev's /dev/serial/by-id links do). RS-485 direction control is not
simulated: a pty has no RS-485 ioctls, and the protocol does not depend on them.
"""

from __future__ import annotations

import logging
import os
import select
import tempfile
import threading
import time
from collections import deque
from collections.abc import Iterable, Sequence
from pathlib import Path

from grassd.firmware_proto.errors import SimulatorError
from grassd.firmware_proto.framing import FrameReader
from grassd.rigs.faults import FaultInjector
from grassd.rigs.firmware import Controller, simulated_config
from grassd.rigs.pty_line import LinePacer, close_fds, open_raw_pty

log = logging.getLogger(__name__)


def make_controllers(state_dir: str | Path, addresses: Iterable[int],
                     **config: object) -> list[Controller]:
    """Controllers with the given addresses, EEPROM files ``state_dir/controller-<a>.eeprom``.

    ``config`` holds further :class:`~.firmware.ControllerConfig` fields (n_pixels, ...).
    Existing EEPROM files are reused, so tables survive a restart of the simulator.
    """
    state_dir = Path(state_dir)
    return [Controller(simulated_config(a, **config),
                       state_dir / f"controller-{a}.eeprom") for a in addresses]


class SimulatedBus:
    """Controllers sharing one simulated serial line, attached to a pty.

    ``link_path``: a symlink kept pointing at the current pty (needed for unplug faults, since a
    re-plugged pty gets a new /dev/pts number). ``baud``: pace the line at this rate (None: as
    fast as the pty goes). ``turnaround_s``: controller processing time before answering.
    ``unplug_power_cycles``: an unplug also power-cycles the controllers (USB-powered boards).
    ``echo``: the host hears its own bytes back, as through an RS-485 adapter with local echo.
    """

    def __init__(self, controllers: Sequence[Controller], *, link_path: str | Path | None = None,
                 baud: int | None = None, faults: FaultInjector | None = None,
                 turnaround_s: float = 0.0, unplug_power_cycles: bool = True,
                 echo: bool = False) -> None:
        if not controllers:
            raise SimulatorError("a simulated bus needs at least one controller")
        addresses = [c.config.address for c in controllers]
        if len(set(addresses)) != len(addresses):
            raise SimulatorError(f"two controllers on one bus share an address: {addresses}")
        if faults is not None and faults.plan.unplug and link_path is None:
            raise SimulatorError("unplug faults need a link_path: the re-plugged pty gets a "
                                 "new device name")
        self.controllers = list(controllers)
        self.link_path = Path(link_path) if link_path is not None else None
        self.baud = baud
        self.faults = faults
        self.turnaround_s = turnaround_s
        self.unplug_power_cycles = unplug_power_cycles
        self.echo = echo
        self.reader = FrameReader()
        self.bytes_from_host = 0
        self.bytes_to_host = 0
        self.frames = 0
        self.unplugs = 0
        self.errors = 0  #: unexpected exceptions while serving (a simulator bug if > 0)
        self.device = ""
        self._master = self._slave = -1
        self._pacer = LinePacer(baud)
        self._replug_at: float | None = None
        self._requests: deque[tuple[float, threading.Event]] = deque()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        if faults is not None:
            for c in self.controllers:
                c.eeprom.tear_hook = faults.tear

    # --- lifecycle ------------------------------------------------------------------------
    @property
    def path(self) -> str:
        """The port a client opens: the stable symlink if any, else the current pty device."""
        return str(self.link_path) if self.link_path is not None else self.device

    def start(self) -> SimulatedBus:
        """Create the pty and start serving the line in a daemon thread."""
        self._plug()
        self._thread = threading.Thread(target=self._run, name=f"simbus:{self.path}",
                                        daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        """Stop serving, close the pty, release the controllers' EEPROM files."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5)
        self._close_pty()
        if self.link_path is not None and self.link_path.is_symlink():
            self.link_path.unlink()
        for c in self.controllers:
            c.close()

    def __enter__(self) -> SimulatedBus:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def _plug(self) -> None:
        self._master, self._slave, self.device = open_raw_pty(self.link_path)
        self.reader.reset()

    def _close_pty(self) -> None:
        close_fds(self._master, self._slave)
        self._master = self._slave = -1

    def unplug(self, down_s: float, wait_s: float = 5.0) -> None:
        """Pull the plug; a fresh pty appears behind :attr:`path` after ``down_s`` seconds.

        Safe from any thread: the bus thread carries it out (between frames) and this call
        returns once the port is gone.
        """
        if threading.current_thread() is self._thread or self._thread is None:
            self._unplug_now(down_s)
            return
        done = threading.Event()
        self._requests.append((down_s, done))
        if not done.wait(wait_s):
            raise SimulatorError("the simulated bus thread did not carry out the unplug")

    def _unplug_now(self, down_s: float) -> None:
        self._close_pty()
        if self.link_path is not None:
            self.link_path.unlink(missing_ok=True)
        if self.unplug_power_cycles:
            for c in self.controllers:
                c.power_cycle()
        self.unplugs += 1
        self._replug_at = time.monotonic() + down_s

    # --- the line -------------------------------------------------------------------------
    def _run(self) -> None:
        while not self._stop.is_set():
            while self._requests:
                down_s, done = self._requests.popleft()
                self._unplug_now(down_s)
                done.set()
            if self._replug_at is not None:
                if time.monotonic() < self._replug_at:
                    time.sleep(0.001)
                    continue
                self._replug_at = None
                self._plug()
            try:
                ready, _, _ = select.select([self._master], [], [], 0.01)
                if not ready:
                    continue
                data = os.read(self._master, 4096)
            except (BlockingIOError, InterruptedError):
                continue
            except (OSError, ValueError):  # no slave open at the moment, or fd closed
                time.sleep(0.001)
                continue
            self.bytes_from_host += len(data)
            if self.echo:
                self._write(data)
            pieces = self.faults.corrupt(data) if self.faults else [(0.0, data)]
            for stall, piece in pieces:
                if stall:
                    time.sleep(stall)
                self._pacer.pace(len(piece))
                for body in self.reader.feed(piece):
                    try:
                        self._on_frame(body)
                    except Exception:  # keep serving: a deaf simulator would hide the bug
                        self.errors += 1
                        log.exception("simulated bus %s: error while handling a frame",
                                      self.path)
                    if self._replug_at is not None:
                        break
                if self._replug_at is not None:
                    break  # the rest of what was in flight is lost with the port

    def _on_frame(self, body: bytes) -> None:
        self.frames += 1
        reboot = None
        target = next((c for c in self.controllers if len(body) > 1
                       and c.config.address == body[1]), None)
        if self.faults is not None:
            down = self.faults.unplug_for()
            if down is not None:
                self._unplug_now(down)
                return
            if target is not None:
                reboot = self.faults.reboot_now()
        if reboot == "before":
            target.power_cycle()
            return
        for c in self.controllers:
            reply = c.handle(body)
            if reply is not None and reboot is None:
                self._send(reply)
        if reboot == "after":  # carried out, but the answer never leaves
            target.power_cycle()

    def _send(self, wire: bytes) -> None:
        if self.turnaround_s:
            time.sleep(self.turnaround_s)
        pieces = self.faults.corrupt(wire) if self.faults else [(0.0, wire)]
        for stall, piece in pieces:
            if stall:
                time.sleep(stall)
            self._pacer.pace(len(piece))
            if not self._write(piece):
                return
            self.bytes_to_host += len(piece)

    def _write(self, data: bytes) -> bool:
        try:
            os.write(self._master, data)
            return True
        except OSError:  # nobody reading / buffer full: bytes are lost, as on a wire
            return False


def start_buses(state_dir: str | Path, count: int, *, shared: bool = True,
                link_dir: str | Path | None = None, baud: int | None = None,
                **config: object) -> list[SimulatedBus]:
    """Start ``count`` simulated controllers: all on one bus (addresses 1..count) if ``shared``,
    else each on its own pty with address 1. Symlinks ``link_dir/bus<i>`` name the ports.
    """
    if count < 1:
        raise SimulatorError(f"need at least one controller, got {count}")
    link_dir = Path(link_dir) if link_dir is not None else Path(tempfile.mkdtemp(prefix="grassd-"))
    link_dir.mkdir(parents=True, exist_ok=True)
    state_dir = Path(state_dir)
    if shared:
        groups = [make_controllers(state_dir, range(1, count + 1), **config)]
    else:
        groups = [make_controllers(state_dir / f"port{i}", [1], **config) for i in range(count)]
    return [SimulatedBus(g, link_path=link_dir / f"bus{i}", baud=baud).start()
            for i, g in enumerate(groups)]
