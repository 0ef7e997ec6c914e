"""Exception hierarchy of :mod:`grassd.calib`: every error says what to fix."""


class CalibError(Exception):
    """Base class of every error raised by grassd.calib."""
