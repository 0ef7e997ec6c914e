"""Exception hierarchy of :mod:`grassd.daemon` and the set of errors shown to users as one line."""

from grassd.calib.errors import CalibError
from grassd.firmware_proto.errors import ProtocolError
from grassd.sim.errors import SimError


class DaemonError(Exception):
    """Base class of every error raised by grassd.daemon."""


class ConfigError(DaemonError):
    """The configuration file is missing, malformed or holds an invalid value."""


#: Errors that the CLI reports as a single line with exit code 2 (no traceback).
USER_ERRORS: tuple[type[Exception], ...] = (CalibError, SimError, ProtocolError, DaemonError)
