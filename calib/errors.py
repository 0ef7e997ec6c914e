"""Exception hierarchy of :mod:`grassd.calib`: every error says what to fix.

All errors derive from :class:`CalibError`; the CLI prints them as one line with exit code 2.
Several also derive from :class:`ValueError` so that generic callers can catch them as such.
"""


class CalibError(Exception):
    """Base class of every error raised by grassd.calib."""


class InvalidArrayError(CalibError, ValueError):
    """An input array is malformed: wrong shape, NaN/Inf, or negative where it must not be."""


class NonFiniteError(InvalidArrayError):
    """An input array holds NaN or Inf values."""


class NegativeValueError(InvalidArrayError):
    """An input array that must be non-negative (linear light, lengths) holds negative values."""


class ShapeError(InvalidArrayError):
    """An input array has the wrong shape or size."""


class TooFewLengthsError(CalibError, ValueError):
    """A characteristic has fewer than three distinct grass lengths."""


class FlatCharacteristicError(CalibError, ValueError):
    """The OGCD range of a characteristic is too small to build a useful 8-bit table."""


class UnknownMethodError(CalibError, KeyError):
    """A method name (colour difference, colour correction, chart) is not known."""

    def __str__(self) -> str:  # KeyError quotes its message; we want it plain.
        return str(self.args[0]) if self.args else ""


class ChartError(CalibError, ValueError):
    """A colour-checker reference chart or a chart file is missing, malformed or inconsistent."""


class GeometryError(CalibError, ValueError):
    """A measurement quadrilateral is degenerate, not convex, or lies outside the image."""


class RawReadError(CalibError, OSError):
    """A RAW file is missing, truncated, corrupt or not a RAW format LibRaw can develop."""


class RawSizeError(RawReadError):
    """A RAW file's header declares a size its reader does not take (``width`` x ``height``
    pixels of its ``what``, "sensor" or "image": beyond the limit, or not the sensor size the
    caller expects); nothing was unpacked."""

    def __init__(self, message: str, *, what: str, width: int, height: int) -> None:
        super().__init__(message)
        self.what, self.width, self.height = what, width, height


class DngWriteError(CalibError, ValueError):
    """The arguments given to the DNG writer cannot produce a valid DNG file."""


class ExposureError(CalibError, ValueError):
    """The grey reference used for exposure normalisation is unusable (black or non-finite)."""


class HdrMergeError(CalibError, ValueError):
    """An exposure bracket cannot be merged into a radiance map (shapes, exposures, response)."""


class BracketClippedError(HdrMergeError):
    """Even the shortest exposure of a bracket is clipped over most of the image."""


class BracketBlackError(HdrMergeError):
    """Even the longest exposure of a bracket is black over most of the image."""


class CornersOutsideImageError(CalibError, ValueError):
    """A quad or checker corner lies outside the photo it belongs to."""


class CheckerPhotoError(CalibError, ValueError):
    """The checker's photo cannot give a white balance: not an R/G/B Bayer sensor, an
    unsupported orientation, a clipped patch, a grey patch too small or black."""


class ClippedCheckerError(CheckerPhotoError):
    """A checker photo's patches clip: near the level where the development saturates a channel
    (``high``) or at the black level (``low``, no light read); 0-based patch indices in the
    chart's reading order. A clipped patch bends any colour correction or white balance fitted
    to the patches."""

    def __init__(self, message: str, *, high: tuple[int, ...], low: tuple[int, ...]) -> None:
        super().__init__(message)
        self.high, self.low = high, low


class CameraResponseError(CalibError, ValueError):
    """A camera's spectral sensitivities, an illuminant or a training set of spectra cannot be
    used: wrong shape, negative, unknown name."""


class SensitivityFileError(CameraResponseError):
    """A CSV of spectral sensitivities is missing or malformed; the message names the line or
    the value to fix."""
