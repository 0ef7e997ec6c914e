"""Exception hierarchy of :mod:`grassd.daemon` and the set of errors shown to users as one line."""

from grassd.calib.errors import CalibError
from grassd.firmware_proto.errors import ProtocolError
from grassd.sim.errors import SimError


class DaemonError(Exception):
    """Base class of every error raised by grassd.daemon."""


class LocatedError(DaemonError):
    """A document a user wrote (configuration, bundle manifest, capture.toml) is malformed or
    holds an invalid value (raised by :mod:`grassd.daemon.core.config.schema`).

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


class ConfigError(LocatedError):
    """The configuration file is missing, malformed or holds an invalid value."""


class IngestError(DaemonError):
    """A bundle in the inbox is malformed; the bundle is rejected with this message as reason."""


class ManifestError(IngestError, LocatedError):
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


class RootRefuses(DaemonError):
    """A command started by root would read, as root, files that another user may change (a
    state directory, the configuration): it stops before reading them
    (:mod:`grassd.daemon.core.runtime.state_owner`)."""


class OthersMayWrite(RootRefuses):
    """Root's own state directory or configuration, but another user may change a part of it
    (it, a file or directory in it, or a directory above it)."""


class OwnerUnknown(RootRefuses):
    """The state directory belongs to a uid without an account, so root cannot become it."""


class SwitchUserFailed(RootRefuses):
    """Root could not become the state directory's owner (no CAP_SETUID or CAP_SETGID)."""


class TransientError(DaemonError):
    """A condition that clears by itself (a service that is down, a connection that dropped):
    the daemon keeps what it was working on and retries with backoff, never rejects it."""


class ComputeUnavailable(TransientError):
    """The Dask cluster of ``[compute] scheduler`` could not run a calibration: the scheduler
    is unreachable, it has no worker, or the worker running the calibration died. The active
    table stays; the bundle waits in processing/ and is retried with backoff."""


class ComputeResultRefused(ComputeUnavailable):
    """A Dask worker answered a calibration (or a sweep's condition) with something other than
    its declared form (:mod:`grassd.daemon.compute.wire`): the answer is dropped unread,
    the bundle waits and is retried as when the cluster is unavailable (a sweep stops; run it
    again to resume). Check the workers' grassd versions and who holds a certificate of the
    site's CA."""


class RunInterrupted(DaemonError):
    """A calibration run was stopped part-way (daemon shutting down); nothing was committed."""


class CalibrationRejected(DaemonError):
    """A calibration run produced a table that failed a sanity check; nothing was pushed."""


class CaptureError(DaemonError):
    """A capture failed; no bundle was written. Retried with backoff by the station."""


class CameraError(CaptureError):
    """The camera could not be driven or did not deliver a usable shot."""


class CameraBusy(CaptureError):
    """Another capture into the same state directory (the daemon's or ``grassd capture``)
    holds the camera; this one did not start."""


class CameraUnreachable(CameraError):
    """No HTTP connection to the camera (wrong URL, camera off, Wi-Fi down, timeout)."""


class CameraHttpError(CameraError):
    """The camera answered an HTTP error status (4xx: our request, 5xx: the camera)."""

    def __init__(self, message: str, status: int) -> None:
        super().__init__(message)
        self.status = status


class CameraProtocolError(CameraError):
    """The camera's answer is not the Open Spherical Camera JSON expected (malformed JSON,
    missing fields, a command in state ``error``)."""


class CameraCommandRefused(CameraHttpError, CameraProtocolError):
    """The camera answered a command with an OSC error object (``state`` "error"): the
    ``command``, the camera's error ``code`` (``invalidParameterValue``, ``disabledCommand``
    ...) and its ``detail`` message as it sent them; ``status`` is the HTTP status they came
    with (200 when the error object came with a success status)."""

    def __init__(self, message: str, status: int, *, command: str, code: str,
                 detail: str) -> None:
        super().__init__(message, status)
        self.command, self.code, self.detail = command, code, detail


class CaptureModeRefused(CameraCommandRefused):
    """The camera would not go into still-image capture (OSC option ``captureMode`` "image")
    before a bracket, or did not report that mode once asked."""


class CameraCommandTimeout(CameraError):
    """A camera command stayed ``inProgress`` longer than the command timeout."""


class CameraDownloadError(CameraError):
    """A shot's file could not be downloaded whole (truncated, wrong size, undecodable)."""


class ExposureMissing(CameraError):
    """A shot's real exposure (shutter time) is neither in its EXIF nor in the camera's
    options, so it cannot be merged."""


class BracketUnusable(CaptureError):
    """The bracket cannot make a radiance map (every shot clipped, or every shot black)."""


#: Errors that the CLI reports as a single line with exit code 2 (no traceback).
USER_ERRORS: tuple[type[Exception], ...] = (CalibError, SimError, ProtocolError, DaemonError)
