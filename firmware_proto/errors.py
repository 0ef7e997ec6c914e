"""Exception hierarchy of :mod:`grassd.firmware_proto`.

:class:`TransientError` and its subclasses mean "retry / reconnect may help"; everything else
is a permanent failure the user must fix.
"""


class ProtocolError(Exception):
    """Base class of every error raised by grassd.firmware_proto."""


class TransientError(ProtocolError):
    """A failure that may go away by itself (timeout, garbled frame, port gone for a while)."""
