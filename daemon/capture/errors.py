"""Typed errors of the capture station; each says what to check or fix."""

from grassd.daemon.errors import DaemonError


class CaptureError(DaemonError):
    """A capture failed; no bundle was written. Retried with backoff by the station."""


class CameraError(CaptureError):
    """The camera could not be driven or did not deliver a usable shot."""


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


class CameraCommandTimeout(CameraError):
    """A camera command stayed ``inProgress`` longer than the command timeout."""


class CameraDownloadError(CameraError):
    """A shot's file could not be downloaded whole (truncated, wrong size, undecodable)."""


class ExposureMissing(CameraError):
    """A shot's real exposure (shutter time) is neither in its EXIF nor in the camera's
    options, so it cannot be merged."""


class BracketUnusable(CaptureError):
    """The bracket cannot make a radiance map (every shot clipped, or every shot black)."""
