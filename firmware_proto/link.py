"""A serial port carrying frames: the boundary where pyserial and OS errors become ours.

:class:`SerialLink` opens the port lazily, feeds what it reads to a
:class:`~.framing.FrameReader`, and on any ``serial.SerialException``, ``OSError`` or
``termios.error`` closes the port and raises :class:`~.errors.PortUnavailable` (transient),
so the next call reopens it by name, which is how a USB controller that was unplugged and
plugged back in is found again.
"""

from __future__ import annotations

import termios
import time
from collections import deque

import serial
import serial.rs485

from grassd.firmware_proto.codec import Frame, read_frames
from grassd.firmware_proto.errors import PortConfigError, PortUnavailable
from grassd.firmware_proto.framing import FrameReader

#: pyserial read timeout used to poll until a deadline (seconds).
POLL_S = 0.005
#: What pyserial lets escape when a device vanishes: its own exception, OSError from os.read /
#: os.write / ioctl, and termios.error from tcdrain / tcsetattr (not an OSError subclass).
PORT_ERRORS = (serial.SerialException, OSError, termios.error)


class SerialLink:
    """Frames over the serial port ``port`` (a device path such as /dev/ttyACM0) at ``baudrate``.

    ``rs485``: switch the UART into the kernel's RS-485 mode (the driver drives the transceiver's
    DE/RE from RTS) for native UARTs wired to a transceiver; leave it off for USB-RS485 adapters
    with automatic direction control, for USB CDC controllers, and for ptys (which have no
    RS-485 ioctls). ``bytes_sent`` / ``bytes_received`` count wire bytes; ``opens`` counts
    (re)opens.
    """

    def __init__(self, port: str, baudrate: int = 115_200, write_timeout_s: float = 1.0,
                 rs485: bool = False) -> None:
        self.port = port
        self.baudrate = baudrate
        self.rs485 = rs485
        self.write_timeout_s = write_timeout_s
        self._ser: serial.Serial | None = None
        self.reader = FrameReader()
        self._pending: deque[Frame] = deque()
        self.bytes_sent = 0
        self.bytes_received = 0
        self.opens = 0

    @property
    def is_open(self) -> bool:
        """True while the port is open."""
        return self._ser is not None

    def open(self) -> None:
        """Open the port if it is closed; raise :class:`PortUnavailable` if it cannot be."""
        if self._ser is not None:
            return
        try:
            ser = serial.Serial(self.port, self.baudrate, timeout=POLL_S,
                                write_timeout=self.write_timeout_s)
            ser.reset_input_buffer()
        except (*PORT_ERRORS, ValueError) as exc:
            raise PortUnavailable(f"cannot open serial port {self.port}: {exc}") from None
        if self.rs485:
            try:
                ser.rs485_mode = serial.rs485.RS485Settings(rts_level_for_tx=True,
                                                            rts_level_for_rx=False)
            except (*PORT_ERRORS, ValueError) as exc:
                ser.close()
                raise PortConfigError(
                    f"serial port {self.port} does not support the kernel's RS-485 mode "
                    f"({exc}); use an adapter with automatic direction control and turn "
                    f"rs485 off") from None
        self._ser = ser
        self.reader.reset()
        self._pending.clear()
        self.opens += 1

    def close(self) -> None:
        """Close the port (safe to call when closed or when the device is already gone)."""
        ser, self._ser = self._ser, None
        if ser is not None:
            try:
                ser.close()
            except PORT_ERRORS:
                pass

    def _fail(self, what: str, exc: BaseException) -> PortUnavailable:
        self.close()
        return PortUnavailable(f"serial port {self.port} {what} failed ({exc}); "
                               f"is the controller unplugged?")

    def send(self, wire: bytes) -> None:
        """Write one encoded frame, opening the port first if needed."""
        self.open()
        assert self._ser is not None
        try:
            self._ser.write(wire)
            self._ser.flush()
        except PORT_ERRORS as exc:
            raise self._fail("write", exc) from None
        self.bytes_sent += len(wire)

    def receive(self, deadline: float) -> Frame | None:
        """The next valid frame received before ``deadline`` (time.monotonic), or None.

        Damaged frames and garbage are skipped (counted in ``reader.stats``).
        """
        self.open()
        assert self._ser is not None
        while not self._pending:
            if time.monotonic() >= deadline:
                return None
            try:
                data = self._ser.read(max(1, self._ser.in_waiting))
            except PORT_ERRORS as exc:
                raise self._fail("read", exc) from None
            if data:
                self.bytes_received += len(data)
                self._pending.extend(read_frames(self.reader, data))
        return self._pending.popleft()
