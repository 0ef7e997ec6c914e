"""Controllers of the C firmware's posix port (``firmware/ports/posix``) as a bus on a pty.

:class:`PosixBus` starts one ``grassfw-posix`` process serving the given addresses on one
pseudo-terminal, and offers what :class:`~.simulator.SimulatedBus` offers its users (``path``,
``device``, ``controllers``, ``unplug``, ``stop``), so host code and tests run unchanged
against the Python model and the C firmware. What a test asks of a controller
(:meth:`NativeController.active_table`, ``eeprom.writes``, ``boots``) is read from the files
the process keeps: its storage (the layout of :mod:`.eeprom`, read here with
:class:`~.eeprom.BankStore`) and its counters.
"""

from __future__ import annotations

import os
import subprocess
import threading
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from grassd.firmware_proto.errors import SimulatorError
from grassd.rigs.eeprom import active_table_in
from grassd.rigs.firmware import ControllerConfig, bus_pixels, simulated_config
from grassd.rigs.native_build import posix_firmware
from grassd.rigs.processes import end_process

#: Exit status of a posix firmware process that lost power at ``--power-cut-at``.
EXIT_POWER_CUT = 3


@dataclass(frozen=True)
class TargetChange:
    """A frame changed ``pixels`` motor targets of controller ``address`` at ``t_ns``
    (CLOCK_MONOTONIC nanoseconds, :func:`time.monotonic_ns` in this process)."""

    t_ns: int
    address: int
    pixels: int


class _Counters:
    def __init__(self, path: Path) -> None:
        self.path = path

    def read(self) -> dict[str, int]:
        words = self.path.read_text().split() if self.path.exists() else []
        return {k: int(v) for k, v in zip(words[::2], words[1::2], strict=True)}

    @property
    def writes(self) -> int:
        """Storage writes and erases since the process started."""
        return self.read().get("writes", 0)


class NativeController:
    """One controller inside a posix firmware process, seen through its files."""

    def __init__(self, config: ControllerConfig, state_dir: Path) -> None:
        self.config = config
        self.storage_path = state_dir / f"controller-{config.address}.eeprom"
        self.eeprom = _Counters(state_dir / f"controller-{config.address}.stats")

    @property
    def boots(self) -> int:
        """Boots since the process started (1, plus one per unplug)."""
        return self.eeprom.read().get("boots", 0)

    def active_table(self) -> np.ndarray | None:
        """The table the controller boots with (um): the valid bank of largest generation."""
        return active_table_in(self.storage_path.read_bytes(), self.config.capacity)


class PosixBus:
    """A posix firmware process serving ``addresses`` on one pty (RS-485 style).

    ``n_pixels``: pixels per controller (one value, or one per address). ``link_path``: a
    symlink kept pointing at the pty (the pty changes on unplug). ``baud``: pace the line at
    this rate (None: as fast as the pty goes). ``power_cut_at``: the process
    loses power at its k-th storage write, when ``power_cut_keep`` ("half", "none" or
    "all-but-one") of that write's bytes have landed (see ``firmware/ports/posix/main.c``).
    ``trace_path``: the process appends a line to this file whenever a frame changed a
    controller's motor targets (:meth:`target_changes` reads it back).
    """

    def __init__(self, state_dir: str | Path, addresses: Sequence[int], *,
                 n_pixels: int | Sequence[int] = ControllerConfig.n_pixels,
                 link_path: str | Path | None = None,
                 max_chunk: int = ControllerConfig.max_chunk, power_cut_at: int | None = None,
                 power_cut_keep: str = "half", baud: int | None = None,
                 trace_path: str | Path | None = None) -> None:
        pixels = bus_pixels("a posix firmware bus", addresses, n_pixels)
        self.state_dir = Path(state_dir)
        self.link_path = Path(link_path) if link_path is not None else None
        self.max_chunk = max_chunk
        self.power_cut_at = power_cut_at
        self.power_cut_keep = power_cut_keep
        self.baud = baud
        self.trace_path = Path(trace_path) if trace_path is not None else None
        self.controllers = [
            NativeController(simulated_config(a, n_pixels=p, max_chunk=max_chunk), self.state_dir)
            for a, p in zip(addresses, pixels, strict=True)]
        self.errors = 0  #: unexpected exits of the firmware process
        self.unplugs = 0
        self.device = ""
        self.proc: subprocess.Popen[str] | None = None
        self._unplugged = threading.Event()
        self._plugged = threading.Event()
        self._reader: threading.Thread | None = None
        self.stderr = ""

    @property
    def path(self) -> str:
        """The port a client opens: the stable symlink if any, else the pty device."""
        return str(self.link_path) if self.link_path is not None else self.device

    def start(self) -> PosixBus:
        """Build (if needed) and start the firmware process; return once its pty exists."""
        exe = posix_firmware()
        self.state_dir.mkdir(parents=True, exist_ok=True)
        cmd = [str(exe), "--state-dir", str(self.state_dir),
               "--addresses", ",".join(str(c.config.address) for c in self.controllers),
               "--pixels", ",".join(str(c.config.n_pixels) for c in self.controllers),
               "--max-chunk", str(self.max_chunk)]
        if self.link_path is not None:
            cmd += ["--link", str(self.link_path)]
        if self.baud:
            cmd += ["--baud", str(self.baud)]
        if self.trace_path is not None:
            cmd += ["--trace", str(self.trace_path)]
        if self.power_cut_at is not None:
            cmd += ["--power-cut-at", f"{self.power_cut_at}:{self.power_cut_keep}"]
        self.proc = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                     stderr=subprocess.PIPE, text=True)
        first = self.proc.stdout.readline().strip() if self.proc.stdout else ""
        if not first:
            err = self.proc.stderr.read() if self.proc.stderr else ""
            self.proc.wait()
            raise SimulatorError(f"the posix firmware did not start: {err.strip()}")
        self.device = os.path.realpath(first)
        self._reader = threading.Thread(target=self._read_stdout, daemon=True,
                                        name=f"posixfw:{self.path}")
        self._reader.start()
        return self

    def target_changes(self) -> list[TargetChange]:
        """Every change of motor targets a frame made so far (needs ``trace_path``), in the
        order they happened."""
        if self.trace_path is None or not self.trace_path.exists():
            return []
        out = []
        for line in self.trace_path.read_text().splitlines():
            words = line.split()
            if len(words) == 3:  # a line being written is left for the next read
                out.append(TargetChange(int(words[0]), int(words[1]), int(words[2])))
        return out

    def _read_stdout(self) -> None:
        assert self.proc is not None and self.proc.stdout is not None
        for line in self.proc.stdout:
            word, _, rest = line.strip().partition(" ")
            if word == "unplugged":
                self._unplugged.set()
            elif word == "plugged":
                self.device = rest
                self._plugged.set()

    def unplug(self, down_s: float, wait_s: float = 5.0) -> None:
        """Pull the plug (the controllers power-cycle); a fresh pty appears behind :attr:`path`
        after ``down_s`` seconds. Returns once the port is gone."""
        if self.proc is None or self.proc.stdin is None:
            raise SimulatorError("start() the posix firmware bus first")
        self._unplugged.clear()
        self._plugged.clear()
        self.proc.stdin.write(f"unplug {max(1, round(down_s * 1000))}\n")
        self.proc.stdin.flush()
        if not self._unplugged.wait(wait_s):
            raise SimulatorError("the posix firmware did not carry out the unplug")
        self.unplugs += 1

    def power_cycle(self) -> None:
        """Restart the firmware process on the storage it left (a clean power cycle: the pty
        and :attr:`device` change, a ``link_path`` follows)."""
        self.stop()
        self.start()

    def wait_exit(self, timeout_s: float = 10.0) -> int:
        """Wait for the process to exit by itself (a power cut); returns its exit status."""
        assert self.proc is not None
        rc = self.proc.wait(timeout_s)
        self.stderr = self.proc.stderr.read() if self.proc.stderr else ""
        return rc

    def stop(self) -> None:
        """Stop the process (SIGTERM, as a clean shutdown) and wait for it."""
        if self.proc is None:
            return
        if self.proc.poll() is None:
            if end_process(self.proc, 5) not in (0, -15):
                self.errors += 1
        elif self.proc.returncode != EXIT_POWER_CUT or self.power_cut_at is None:
            self.errors += 1
        if self._reader is not None:  # the process is gone: its stdout ends
            self._reader.join(5)
        for f in (self.proc.stdin, self.proc.stdout, self.proc.stderr):
            if f is not None:
                try:
                    if f is self.proc.stderr and not self.stderr:
                        self.stderr = f.read()
                    f.close()
                except (OSError, ValueError):
                    pass
        if self.link_path is not None and self.link_path.is_symlink():
            self.link_path.unlink()

    def __enter__(self) -> PosixBus:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()
