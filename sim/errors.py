"""Exception hierarchy of :mod:`grassd.sim`: every error says what to fix."""


class SimError(Exception):
    """Base class of every error raised by grassd.sim."""


class HdriError(SimError):
    """The environment map is missing, corrupt, of the wrong shape or holds unusable values."""


class HdriTooLarge(HdriError):
    """The environment map's header declares more texels than the reader that asked takes
    (``width`` x ``height`` texels against ``limit``); nothing was decoded."""

    def __init__(self, message: str, *, width: int, height: int, limit: int) -> None:
        super().__init__(message)
        self.width, self.height, self.limit = width, height, limit


class LightingError(SimError):
    """Lux, sun or scaling parameters are out of range or inconsistent with the map."""


class SceneError(SimError):
    """Pixel/display geometry or viewpoint parameters are invalid."""


class RendererMissing(SimError):
    """Taichi, which the renderer needs, cannot be imported here (no wheels for this platform,
    or installed without ``grassd[sim]``); raised by :mod:`grassd.sim.backend` and
    :func:`require_renderer`, worded by :func:`renderer_missing`."""


def renderer_missing(why: str) -> RendererMissing:
    """The one-line error of every command that needs the renderer where Taichi cannot be
    imported (``why``: the import's own message), naming the platform and the two ways out."""
    import platform
    import sys

    if "libX11" in why:  # the wheel links it; the Makefile's venv has a stand-in for it
        return RendererMissing(
            f"the renderer needs Taichi, whose module needs libX11 ({why}): apt-get install "
            "libx11-6, or set the venv up with the Makefile (make setup), which gives it a "
            "stand-in where the system has none")
    return RendererMissing(
        f"the renderer needs Taichi, which is not installed here ({sys.platform} "
        f"{platform.machine()}, Python {platform.python_version()}: {why}); Taichi has wheels "
        "for x86-64 Linux and Windows and for Apple silicon macOS: pip install 'grassd[sim]' "
        "there, or set [compute] scheduler = \"tls://host:8786\" and its TLS files (grassd "
        "calibrate --scheduler) to simulate on a Dask cluster whose workers have it")


def require_renderer() -> None:
    """Raise :func:`renderer_missing` unless Taichi can be imported, without importing it: for
    a process that leaves the rendering to child processes (the studio, a local sweep), so
    that the user reads the reason rather than a child that died."""
    import importlib.util

    try:
        found = importlib.util.find_spec("taichi") is not None
    except (ImportError, ValueError) as exc:
        raise renderer_missing(str(exc)) from None
    if not found:
        raise renderer_missing("No module named 'taichi'")
