"""Exception hierarchy of :mod:`grassd.sim`: every error says what to fix."""


class SimError(Exception):
    """Base class of every error raised by grassd.sim."""


class HdriError(SimError):
    """The environment map is missing, corrupt, of the wrong shape or holds unusable values."""


class LightingError(SimError):
    """Lux, sun or scaling parameters are out of range or inconsistent with the map."""


class SceneError(SimError):
    """Pixel/display geometry or viewpoint parameters are invalid."""


class RendererMissing(SimError):
    """Taichi, which the renderer needs, cannot be imported here (no wheels for this platform,
    or installed without ``grassd[sim]``); raised by :mod:`grassd.sim.backend`."""
