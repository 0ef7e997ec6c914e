"""Controllers of the C firmware's Cortex-M7 image, each a ``qemu-system-arm -M mps2-an500``
instance, joined into one RS-485-style bus on a pty by a small relay.

Each instance gets its configuration (address, pixel count, max_chunk, uid) through QEMU's
``-device loader`` into a RAM block the firmware reads at boot, and its CMSDK UART on
``-serial pty``. The relay thread forwards every byte the host writes to every instance and
every answer back to the host, as an RS-485 bus does. :class:`QemuBus` offers what
:class:`~.simulator.SimulatedBus` offers (``path``, ``device``, ``controllers``, ``unplug``,
``stop``). A controller's storage lives in the MCU's RAM (a ``.noinit`` array, kept over a
system reset, gone when QEMU exits): :meth:`QemuController.active_table` dumps it through QMP
(``pmemsave``) and reads it with :class:`~.eeprom.BankStore`.
"""

from __future__ import annotations

import json
import os
import re
import select
import shutil
import socket
import struct
import subprocess
import tempfile
import threading
import time
import tty
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from grassd.firmware_proto.codec import Frame, encode_frame
from grassd.firmware_proto.errors import SimulatorError
from grassd.firmware_proto.framing import FrameReader
from grassd.firmware_proto.messages import Hello
from grassd.rigs.eeprom import BankStore, active_table_in
from grassd.rigs.firmware import ControllerConfig, bus_pixels, simulated_config
from grassd.rigs.native_build import FirmwareUnavailable, mps2_image
from grassd.rigs.processes import end_process
from grassd.rigs.pty_line import LinePacer, close_fds, open_raw_pty

#: Where the firmware reads its configuration (ports/mps2/mps2.ld, .fwconfig).
CONFIG_ADDR = 0x203FFF00
CONFIG_MAGIC = 0x47464346  # "FCFG"
_PTY_RE = re.compile(r"char device redirected to (/dev/pts/\d+)")


def _symbols(elf: Path) -> dict[str, int]:
    nm = shutil.which("arm-none-eabi-nm")
    if nm is None:
        raise FirmwareUnavailable("arm-none-eabi-nm is not on PATH: apt-get install "
                                  "gcc-arm-none-eabi")
    out = subprocess.run([nm, str(elf)], capture_output=True, text=True, check=True).stdout
    return {f[2]: int(f[0], 16) for f in (line.split() for line in out.splitlines())
            if len(f) == 3}


class _Qmp:
    """A QMP connection to one QEMU instance (JSON commands over a unix socket)."""

    def __init__(self, path: Path, timeout_s: float = 10.0) -> None:
        deadline = time.monotonic() + timeout_s
        while True:
            try:
                self.sock = socket.socket(socket.AF_UNIX)
                self.sock.settimeout(timeout_s)
                self.sock.connect(str(path))
                break
            except OSError:
                self.sock.close()
                if time.monotonic() > deadline:
                    raise SimulatorError(f"QEMU's QMP socket {path} did not appear") from None
                time.sleep(0.02)
        self.file = self.sock.makefile("rw")
        self._read()  # greeting
        self.command("qmp_capabilities")

    def _read(self) -> dict:
        while True:
            line = self.file.readline()
            if not line:
                raise SimulatorError("QEMU closed its QMP socket")
            msg = json.loads(line)
            if "event" not in msg:
                return msg

    def command(self, name: str, **arguments: object) -> object:
        self.file.write(json.dumps({"execute": name, "arguments": arguments}) + "\n")
        self.file.flush()
        msg = self._read()
        if "error" in msg:
            raise SimulatorError(f"QEMU refused {name}: {msg['error'].get('desc')}")
        return msg.get("return")

    def close(self) -> None:
        self.file.close()
        self.sock.close()


class _Instance:
    """One qemu-system-arm process: its QMP connection and its serial pty (opened raw)."""

    def __init__(self, elf: Path, workdir: Path, config: ControllerConfig,
                 extra_args: Sequence[str] = ()) -> None:
        self.qmp_path = workdir / f"qmp-{config.address}.sock"
        self.qmp_path.unlink(missing_ok=True)
        words = [CONFIG_MAGIC, config.address, config.n_pixels, config.max_chunk, config.uid]
        loaders = []
        for i, w in enumerate(words):
            loaders += ["-device", f"loader,addr={CONFIG_ADDR + 4 * i:#x},data={w:#x},"
                                   f"data-len=4"]
        cmd = [shutil.which("qemu-system-arm") or "qemu-system-arm", "-M", "mps2-an500",
               "-display", "none", "-monitor", "none", "-serial", "pty",
               "-qmp", f"unix:{self.qmp_path},server=on,wait=off", "-kernel", str(elf),
               *loaders, *extra_args]
        self.log = workdir / f"qemu-{config.address}.log"
        with open(self.log, "w") as log:  # QEMU names its pty there; nothing blocks on a pipe
            self.proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT,
                                         stdin=subprocess.DEVNULL)
        deadline = time.monotonic() + 20.0
        while not (m := _PTY_RE.search(self.log.read_text())):
            if self.proc.poll() is not None or time.monotonic() > deadline:
                self.proc.kill()
                self.proc.wait()
                raise SimulatorError(f"qemu-system-arm did not start: "
                                     f"{self.log.read_text().strip()}")
            time.sleep(0.01)
        self.pty = m.group(1)
        self.fd = os.open(self.pty, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
        tty.setraw(self.fd)
        self.qmp = _Qmp(self.qmp_path)
        self.address = config.address

    def wait_ready(self, timeout_s: float = 20.0) -> None:
        """Wait until the firmware answers a HELLO on this instance's pty: QEMU notices that
        its pty was opened only on its next poll (up to a second) and reads nothing until then.
        The HELLOs sent meanwhile then arrive at once and are all answered: those answers are
        drained here, so that none reaches the host.
        """
        reader = FrameReader()
        deadline = time.monotonic() + timeout_s
        seq = 0xFF00
        while time.monotonic() < deadline:
            os.write(self.fd, b"\x00" + encode_frame(Frame(self.address, seq, Hello())))
            seq += 1
            if self._read_until_silent(reader, first_s=0.3):
                return
        raise SimulatorError(f"the firmware in QEMU (address {self.address}) did not answer "
                             f"within {timeout_s:g} s; see {self.log}")

    def _read_until_silent(self, reader: FrameReader, first_s: float) -> bool:
        """Read frames from the instance until it is silent for 0.2 s after the first one
        (waiting up to ``first_s`` for that); True when any frame came."""
        got = False
        wait = first_s
        while select.select([self.fd], [], [], wait)[0]:
            try:
                got |= bool(reader.feed(os.read(self.fd, 4096)))
            except BlockingIOError:
                continue
            if got:
                wait = 0.2
        return got

    def stop(self) -> int | None:
        for close in (lambda: os.close(self.fd), self.qmp.close):
            try:
                close()
            except OSError:
                pass
        if self.proc.poll() is None:
            end_process(self.proc, 5)
            return None
        return self.proc.returncode


class _RamCounters:
    def __init__(self, ctl: QemuController) -> None:
        self._ctl = ctl

    @property
    def writes(self) -> int:
        """Storage writes and erases since QEMU started."""
        return self._ctl._stats()[2]


class QemuController:
    """One controller in its QEMU instance, seen through QMP memory dumps."""

    def __init__(self, config: ControllerConfig, bus: QemuBus) -> None:
        self.config = config
        self._bus = bus
        self.eeprom = _RamCounters(self)

    def _dump(self, symbol: str, size: int) -> bytes:
        inst = self._bus._instances[self.config.address]
        with tempfile.NamedTemporaryFile(dir=self._bus.workdir, suffix=".bin") as f:
            with self._bus._lock:
                inst.qmp.command("pmemsave", val=self._bus._symbols[symbol], size=size,
                                 filename=f.name)
            return Path(f.name).read_bytes()

    def _stats(self) -> tuple[int, ...]:
        """magic, boots, storage writes, storage size, longest byte (SysTick counts), and
        the type of the frame that byte completed (ports/mps2/main.c, board_stats)."""
        return struct.unpack("<6I", self._dump("fw_stats", 24))

    def worst_byte(self) -> tuple[int, int]:
        """(SysTick counts, frame type) of the longest time the firmware spent on one received
        byte since QEMU started; a count is 1/25 MHz, 40 instructions under ``-icount
        shift=0``."""
        stats = self._stats()
        return stats[4], stats[5]

    @property
    def boots(self) -> int:
        """Boots since QEMU started (1, plus one per unplug)."""
        return self._stats()[1]

    def active_table(self) -> np.ndarray | None:
        """The table the controller boots with (um), read from its RAM storage."""
        data = self._dump("fw_storage", BankStore.required_size(self.config.capacity))
        return active_table_in(data, self.config.capacity)


class QemuBus:
    """QEMU instances running the Cortex-M7 firmware, one per address, relayed onto one pty.

    ``n_pixels``: per controller (one value, or one per address; at most 16, the image's
    FW_MAX_PIXELS). ``link_path``: a symlink kept pointing at the host-side pty. ``baud``:
    pace the relayed line (None: unpaced). ``state_dir`` holds the QMP sockets and dumps.
    ``qemu_args``: more qemu-system-arm options (e.g. ``-icount shift=0`` to count
    instructions).
    """

    def __init__(self, state_dir: str | Path, addresses: Sequence[int], *,
                 n_pixels: int | Sequence[int] = ControllerConfig.n_pixels,
                 link_path: str | Path | None = None,
                 baud: int | None = None, max_chunk: int = ControllerConfig.max_chunk,
                 qemu_args: Sequence[str] = ()) -> None:
        pixels = bus_pixels("a QEMU bus", addresses, n_pixels)
        if max(pixels) > 16:
            raise SimulatorError(f"the mps2-an500 image drives at most 16 pixels, "
                                 f"got {max(pixels)}")
        self.workdir = Path(state_dir)
        self.link_path = Path(link_path) if link_path is not None else None
        self.baud = baud
        self.qemu_args = tuple(qemu_args)
        self.controllers = [
            QemuController(simulated_config(a, n_pixels=p, max_chunk=max_chunk), self)
            for a, p in zip(addresses, pixels, strict=True)]
        self.errors = 0
        self.unplugs = 0
        self.device = ""
        self._instances: dict[int, _Instance] = {}
        self._symbols: dict[str, int] = {}
        self._lock = threading.Lock()
        self._master = self._slave = -1
        self._replug_at: float | None = None
        self._requests: list[tuple[float, threading.Event]] = []
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._pacer = LinePacer(baud)

    @property
    def path(self) -> str:
        """The port a client opens: the stable symlink if any, else the pty device."""
        return str(self.link_path) if self.link_path is not None else self.device

    def start(self) -> QemuBus:
        """Build the image if needed, start one QEMU per controller and the relay."""
        elf = mps2_image()
        self._symbols = _symbols(elf)
        self.workdir.mkdir(parents=True, exist_ok=True)
        try:
            for c in self.controllers:
                self._instances[c.config.address] = _Instance(elf, self.workdir, c.config,
                                                              self.qemu_args)
            for inst in self._instances.values():
                inst.wait_ready()
            self._plug()
        except BaseException:
            self.stop()
            raise
        self._thread = threading.Thread(target=self._relay, daemon=True,
                                        name=f"qemubus:{self.path}")
        self._thread.start()
        return self

    def _plug(self) -> None:
        self._master, self._slave, self.device = open_raw_pty(self.link_path)

    def _close_pty(self) -> None:
        close_fds(self._master, self._slave)
        self._master = self._slave = -1

    def _relay(self) -> None:
        fds = {inst.fd for inst in self._instances.values()}
        while not self._stop.is_set():
            while self._requests:
                down_s, done = self._requests.pop(0)
                self._unplug_now(down_s)
                done.set()
            if self._replug_at is not None and time.monotonic() >= self._replug_at:
                self._replug_at = None
                self._plug()
            watch = list(fds) + ([self._master] if self._master >= 0 else [])
            try:
                ready, _, _ = select.select(watch, [], [], 0.01)
            except (OSError, ValueError):
                continue
            for fd in ready:
                try:
                    data = os.read(fd, 4096)
                except (BlockingIOError, InterruptedError):
                    continue
                except OSError:
                    continue
                if not data:
                    continue
                self._pacer.pace(len(data))
                targets = fds if fd == self._master else [self._master]
                for t in targets:
                    if t < 0:
                        continue
                    try:
                        os.write(t, data)
                    except OSError:
                        pass  # nobody reading: lost, as on a wire

    def power_cycle(self, timeout_s: float = 10.0) -> None:
        """Reset every controller (QEMU ``system_reset``: RAM storage is kept) and return once
        each has booted again and listens on its UART."""
        before = {c.config.address: c.boots for c in self.controllers}
        with self._lock:
            for inst in self._instances.values():
                inst.qmp.command("system_reset")
        deadline = time.monotonic() + timeout_s
        for c in self.controllers:
            while c.boots <= before[c.config.address]:
                if time.monotonic() > deadline:
                    raise SimulatorError(f"controller {c.config.address} did not boot again "
                                         f"after a reset")
                time.sleep(0.002)

    def unplug(self, down_s: float, wait_s: float = 5.0) -> None:
        """Pull the plug: the host pty goes away, every controller is reset (power cycle), and
        a fresh pty appears behind :attr:`path` after ``down_s`` seconds."""
        done = threading.Event()
        self._requests.append((down_s, done))
        if not done.wait(wait_s):
            raise SimulatorError("the QEMU bus relay did not carry out the unplug")

    def _unplug_now(self, down_s: float) -> None:
        self._close_pty()
        if self.link_path is not None:
            self.link_path.unlink(missing_ok=True)
        with self._lock:
            for inst in self._instances.values():
                inst.qmp.command("system_reset")
        self.unplugs += 1
        self._replug_at = time.monotonic() + down_s

    def stop(self) -> None:
        """Stop the relay and every QEMU instance."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(5)
        self._close_pty()
        for inst in self._instances.values():
            if inst.stop() is not None:  # it had exited by itself
                self.errors += 1
        self._instances.clear()
        if self.link_path is not None and self.link_path.is_symlink():
            self.link_path.unlink()

    def __enter__(self) -> QemuBus:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()
