"""The messages of the Open Spherical Camera API that grassd sends and reads, as the JSON
objects they are (:mod:`grassd.daemon.camera.client` speaks them). A camera's answer is
not trusted: the client checks the keys it reads before it reads them."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, SupportsFloat, TypeAlias, TypedDict

ExifValue: TypeAlias = SupportsFloat | str | Sequence[SupportsFloat] | None
"""An EXIF or OSC number as cameras write it: a number, a rational, ``"1/1000"`` or
``[num, den]`` (or None when absent)."""


class OscFileFormat(TypedDict, total=False):
    """The ``fileFormat`` option: the picture's type and size in pixels."""

    type: str
    width: int
    height: int


class OscOptions(TypedDict, total=False):
    """The camera options grassd sets and reads (OSC ``camera.setOptions``/``getOptions``):
    shutter in s, ISO, aperture as an f-number, exposureProgram 1 manual, 9 ISO priority."""

    captureMode: str
    exposureProgram: int
    iso: int
    whiteBalance: str
    shutterSpeed: float
    aperture: float
    fileFormat: OscFileFormat


class OscResults(TypedDict, total=False):
    """A finished command's ``results``: the shot's URLs (``_dngFileUrl`` a THETA's raw), the
    options asked, or the EXIF of ``camera._getMetadata``."""

    fileUrl: str
    _dngFileUrl: str
    options: OscOptions
    exif: dict[str, ExifValue]


class OscErrorBody(TypedDict, total=False):
    """An OSC command's ``error``: its code (``invalidParameterValue``, ...) and message."""

    code: str
    message: str


class OscCommand(TypedDict, total=False):
    """An OSC command object as a camera answers it (``/osc/commands/execute`` and
    ``/status``): state "done" with ``results``, "inProgress" with an ``id``, or "error"."""

    name: str
    state: str
    id: str | int
    results: OscResults
    error: OscErrorBody


class OscState(TypedDict, total=False):
    """``/osc/state``: the state's fingerprint and the vendor's state object (its keys differ
    by model; grassd only checks that it is one)."""

    fingerprint: str
    state: dict[str, Any]


class OscParameters(TypedDict, total=False):
    """The ``parameters`` of the commands grassd sends."""

    options: OscOptions
    optionNames: list[str]
    fileUrl: str


class OscRequest(TypedDict, total=False):
    """A command sent to ``/osc/commands/execute`` (``name``, ``parameters``) or a poll of
    ``/osc/commands/status`` (``id``)."""

    name: str
    parameters: OscParameters
    id: str | int
