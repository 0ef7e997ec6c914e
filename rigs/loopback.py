"""An in-process line to simulated controllers, for pushing thousands of tables in seconds.

:class:`LoopbackLink` has :class:`~grassd.firmware_proto.link.SerialLink`'s interface (``send``,
``receive``, ``close``, ``reader``, counters), so
:class:`~grassd.firmware_proto.client.ControllerClient` runs its real request, retry, adaptive-chunk
and framing code over it. What the host sends goes through a :class:`~.faults.FaultInjector` (byte
faults, controller reboots), a :class:`~grassd.firmware_proto.framing.FrameReader` and
:meth:`~.firmware.Controller.handle`, the answers through the injector and the host's reader,
exactly as on :class:`~.simulator.SimulatedBus`, but in the calling thread: nothing is paced, and a
frame that was lost makes ``receive`` return None at once instead of waiting out the timeout. So it
measures what the code decides (corrupt or mixed tables, successes, tries), not timing: for timing
use a :class:`~.simulator.SimulatedBus` on a pty. Unplug faults are not simulated here (they need a
device node).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Sequence

from grassd.firmware_proto.codec import Frame, read_frames
from grassd.firmware_proto.errors import SimulatorError
from grassd.firmware_proto.framing import FrameReader
from grassd.rigs.faults import FaultInjector
from grassd.rigs.firmware import Controller


class LoopbackLink:
    """Frames between the host and ``controllers`` in-process, through ``faults`` if given.

    ``baudrate`` is only reported (the client sizes timeouts with it); ``port`` names the line.
    """

    def __init__(self, controllers: Sequence[Controller], faults: FaultInjector | None = None,
                 port: str = "loopback", baudrate: int = 115_200) -> None:
        if not controllers:
            raise SimulatorError("a loopback line needs at least one controller")
        self.controllers = list(controllers)
        self.faults = faults
        self.port = port
        self.baudrate = baudrate
        self.reader = FrameReader()  # the host's side
        self.bus_reader = FrameReader()  # the controllers' side
        self._pending: deque[Frame] = deque()
        self.bytes_sent = 0
        self.bytes_received = 0
        self.opens = 1
        if faults is not None:
            for c in self.controllers:
                c.eeprom.tear_hook = faults.tear

    @property
    def is_open(self) -> bool:
        """Always True: the line cannot be unplugged."""
        return True

    def open(self) -> None:
        """Nothing to open."""

    def close(self) -> None:
        """Nothing to close (the controllers' EEPROM files stay open; close them yourself)."""

    def _corrupt(self, data: bytes) -> bytes:
        if self.faults is None:
            return data
        return b"".join(piece for _, piece in self.faults.corrupt(data))

    def send(self, wire: bytes) -> None:
        """Deliver one frame to the controllers; queue what they answer for :meth:`receive`."""
        self.bytes_sent += len(wire)
        for body in self.bus_reader.feed(self._corrupt(wire)):
            for reply in self._serve(body):
                self._hear(self._corrupt(reply))

    def _serve(self, body: bytes) -> list[bytes]:
        target = next((c for c in self.controllers if len(body) > 1
                       and c.config.address == body[1]), None)
        reboot = self.faults.reboot_now() if self.faults is not None and target else None
        if reboot == "before":
            target.power_cycle()
            return []
        replies = [r for c in self.controllers if (r := c.handle(body)) is not None]
        if reboot == "after":  # carried out, but the answer never leaves
            target.power_cycle()
            return []
        return replies

    def _hear(self, data: bytes) -> None:
        self.bytes_received += len(data)
        self._pending.extend(read_frames(self.reader, data))

    def receive(self, deadline: float) -> Frame | None:
        """The next frame the host heard, or None at once when none is queued (``deadline``
        is ignored: nothing more can arrive)."""
        return self._pending.popleft() if self._pending else None
