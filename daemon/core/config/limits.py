"""How much the daemon reads of what others write: the caps on a light bundle.

The inbox is writable by an upload service (the ``grassd-upload`` group), so everything in it is
treated as hostile: the caps below bound the bytes and entries the daemon reads before it decides
to reject a bundle. They are the ``[light.limits]`` table of the configuration, and
:data:`FUTURE_TOLERANCE_S` is ``[light] future_tolerance_s``; each default is written once, here
(:mod:`grassd.daemon.core.store.ingest` reads them from here: the store depends on the config, never
the other way round).
"""

from __future__ import annotations

from dataclasses import dataclass

KIB = 1024
MIB = 1024 * 1024


@dataclass(frozen=True)
class BundleLimits:
    """Caps on one light bundle (``[light.limits]``).

    ``manifest_kib``: the manifest file (KiB; a real one is well under 1 KiB, a capture
    station's with its ``[capture]`` table a few KiB); ``file_mib``: each data file (MiB; an
    8K float EXR panorama is about 400 MiB uncompressed, a camera DNG 20-60 MiB);
    ``bundle_mib``: all of a bundle's files together (MiB); ``entries``: files and directories
    in a directory bundle (a real one has two to four).
    """

    manifest_kib: int = 64
    file_mib: int = 512
    bundle_mib: int = 1024
    entries: int = 64

    @property
    def manifest_bytes(self) -> int:
        """``manifest_kib`` in bytes."""
        return self.manifest_kib * KIB

    @property
    def file_bytes(self) -> int:
        """``file_mib`` in bytes."""
        return self.file_mib * MIB

    @property
    def bundle_bytes(self) -> int:
        """``bundle_mib`` in bytes."""
        return self.bundle_mib * MIB


#: The caps when the configuration sets none.
DEFAULT_LIMITS = BundleLimits()


#: How far (s) a bundle's light may be stamped ahead of the daemon's clock (clocks drift; a
#: camera synchronised by NTP is within a second). Config: ``[light] future_tolerance_s``.
FUTURE_TOLERANCE_S = 300.0
