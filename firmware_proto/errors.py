"""Exception hierarchy of :mod:`grassd.firmware_proto`.

:class:`TransientError` and its subclasses mean "retry / reconnect may help"; everything else
is a permanent failure the user must fix. Serial-port exceptions (``serial.SerialException``,
``OSError``) are translated into these at the port boundary (:mod:`.link`), never leaked.
"""

from __future__ import annotations


class ProtocolError(Exception):
    """Base class of every error raised by grassd.firmware_proto."""


class TransientError(ProtocolError):
    """A failure that may go away by itself (timeout, garbled frame, port gone for a while)."""


class FrameError(TransientError):
    """Bytes that do not decode to a valid frame (bad COBS, CRC, length, version or field).

    The only exception the codec raises on bad input; a receiver drops the frame and goes on.
    """


class ControllerTimeout(TransientError):
    """A controller did not answer a request in time, after every retry."""


class PortUnavailable(TransientError):
    """The serial port could not be opened, or vanished while in use (unplugged)."""


class TransferInterrupted(TransientError):
    """A table transfer was lost by the controller (it rebooted, or the staged data was corrupt)."""


class AddressError(ProtocolError):
    """A controller address outside 1..247 was given."""


class PortConfigError(ProtocolError):
    """The serial port cannot be set up as asked (e.g. kernel RS-485 mode on a USB adapter)."""


class NakError(ProtocolError):
    """The controller refused a request with a NAK it will repeat (a permanent refusal).

    ``code`` is the NAK error code (see PROTOCOL.md section 3), ``detail`` its detail word.
    """

    def __init__(self, message: str, *, code: int, detail: int) -> None:
        super().__init__(message)
        self.code = code
        self.detail = detail


class TableError(ProtocolError):
    """A length table is not valid for the target controller (shape, dtype, range, capacity)."""


class TableFileError(ProtocolError):
    """A table file could not be read or does not hold 256-entry length tables."""


class PushFailed(TransientError):
    """A table push did not make the new table active; ``active`` is what is active instead.

    Raised only after transient failures outlasted every retry; a later push may succeed.

    ``active`` is the :class:`~grassd.firmware_proto.messages.TableStatus` read back after the
    failure (the old table), or ``None`` when the controller could not be reached to read it.
    """

    def __init__(self, message: str, *, active: object | None, cause: BaseException | None = None):
        super().__init__(message)
        self.active = active
        self.cause = cause


class SimulatorError(ProtocolError):
    """The simulated controllers could not be started (pty, state directory, bad settings)."""
