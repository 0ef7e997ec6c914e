"""Exception hierarchy of :mod:`grassd.daemon` and the set of errors shown to users as one line."""

from grassd.calib.errors import CalibError
from grassd.firmware_proto.errors import ProtocolError
from grassd.sim.errors import SimError


class DaemonError(Exception):
    """Base class of every error raised by grassd.daemon."""


class ConfigError(DaemonError):
    """The configuration file is missing, malformed or holds an invalid value.

    ``key`` is the dotted key path (e.g. ``controllers[1].baud``), ``line`` the 1-based line of
    the file where it was found (``None`` when it could not be located), ``path`` the file.
    """

    def __init__(
        self,
        message: str,
        *,
        key: str | None = None,
        line: int | None = None,
        path: str | None = None,
    ) -> None:
        where = ""
        if path is not None:
            where = f"{path}:{line}: " if line is not None else f"{path}: "
        what = f"{key}: " if key else ""
        super().__init__(f"{where}{what}{message}")
        self.key = key
        self.line = line
        self.path = path
        self.reason = message


class IngestError(DaemonError):
    """A bundle in the inbox is malformed; the bundle is rejected with this message as reason."""


class ManifestError(IngestError):
    """The bundle manifest cannot be parsed or holds invalid values (e.g. lux <= 0)."""


class LuxSensorError(DaemonError):
    """The Modbus lux sensor could not be read (unreachable, silent or returning nonsense)."""


class LuxSensorUnreachable(LuxSensorError):
    """No connection to the Modbus lux sensor could be opened."""


class LuxSensorSilent(LuxSensorError):
    """The Modbus lux sensor is connected but did not answer (timeout) or answered an exception."""


class HistoryError(DaemonError):
    """The state database cannot be opened or is inconsistent."""


class ControlError(DaemonError):
    """The control socket request failed, or no daemon is listening on it."""


class DaemonNotRunning(ControlError):
    """No running daemon answered on the control socket."""


class DaemonBusy(ControlError):
    """The daemon refused a control request for now (too many clients or queued runs)."""


class StateDirLocked(DaemonError):
    """Another grassd process (daemon or one-shot) holds the state directory's lock."""


class StateDirUnwritable(DaemonError):
    """The state directory's lock file cannot be created or opened (read-only, permissions)."""


class RunInterrupted(DaemonError):
    """A calibration run was stopped part-way (daemon shutting down); nothing was committed."""


class CalibrationRejected(DaemonError):
    """A calibration run produced a table that failed a sanity check; nothing was pushed."""


#: Errors that the CLI reports as a single line with exit code 2 (no traceback).
USER_ERRORS: tuple[type[Exception], ...] = (CalibError, SimError, ProtocolError, DaemonError)
