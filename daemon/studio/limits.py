"""How much of the studio one client may hold: the caps of ``grassd studio`` as a server.

The studio has no section in the daemon's configuration (it is a tool run by a person, not the
service); its caps are written once, here, each with its bounds, and documented in
``docs/studio.md`` ("The studio as a bounded server"). :class:`StudioLimits` checks its values
against :data:`BOUNDS` when it is made, so a studio given other caps (a test's, a future
command-line option's) cannot be given ones that disable a guard.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

from grassd.daemon.studio.inputs import StudioInputError

MIB = 2**20


class StudioLimitError(StudioInputError):
    """A studio cap outside its bounds; the message names it and its bounds."""


@dataclass(frozen=True)
class StudioLimits:
    """The studio's caps.

    Connections: ``header_s`` (s) for a connection's request line and headers to arrive (from
    the connection's opening, and from the end of its previous response); ``header_fields``
    header lines a request may have (each of at most 8190 bytes, aiohttp's own cap: a browser
    sends about 20; a request with more is answered 400); ``body_idle_s`` (s)
    the longest wait for the next piece of a request's body, ``body_s`` (s) for the whole of
    it; ``connections`` open at once (at the cap, a new connection closes the oldest that is
    waiting for its headers or idle between requests; a new one is refused only when every
    open one is being served).

    Pages: ``outbox_messages`` and ``outbox_mib`` (MiB) of messages waiting to be sent to one
    page's WebSocket; a page whose outbox is full (it does not read) is closed, 1008.

    Uploads: ``upload_slots`` uploads read and decoded at once (a 503 beyond them);
    ``kept_uploads`` uploaded HDRIs kept and ``kept_upload_mib`` (MiB) their files together
    (the oldest dropped first); ``kept_maps`` panoramas kept decoded in the simulator (the
    least recently used dropped, read again when chosen).

    Jobs: ``job_cost`` the most a characteristic may cost (:mod:`grassd.daemon.studio.cost`:
    one unit is one length refined to 0.1 dE00 without sun or splay); ``slice_s`` (s) a page's
    job runs while another page's waits before it gives way (doubled for the job at each
    turn it gives, so that every job ends).
    """

    header_s: float = 5.0
    header_fields: int = 48
    body_idle_s: float = 10.0
    body_s: float = 120.0
    connections: int = 128
    outbox_messages: int = 256
    outbox_mib: int = 16
    upload_slots: int = 1
    kept_uploads: int = 4
    kept_upload_mib: int = 512
    kept_maps: int = 3
    job_cost: float = 2000.0
    slice_s: float = 1.0

    def __post_init__(self) -> None:
        for f in fields(self):
            lo, hi = BOUNDS[f.name]
            v = getattr(self, f.name)
            if isinstance(v, bool) or not isinstance(v, int | float) or not lo <= v <= hi:
                raise StudioLimitError(f"the studio's {f.name} is {v!r}; give a number from "
                                       f"{lo} to {hi}")

    @property
    def outbox_bytes(self) -> int:
        """``outbox_mib`` in bytes."""
        return self.outbox_mib * MIB

    @property
    def kept_upload_bytes(self) -> int:
        """``kept_upload_mib`` in bytes."""
        return self.kept_upload_mib * MIB


#: Each cap's smallest and largest value (inclusive).
BOUNDS: dict[str, tuple[float, float]] = {
    "header_s": (0.5, 60.0),
    "header_fields": (16, 128),
    "body_idle_s": (0.5, 120.0),
    "body_s": (1.0, 3600.0),
    "connections": (8, 1000),
    "outbox_messages": (16, 4096),
    "outbox_mib": (1, 256),
    "upload_slots": (1, 8),
    "kept_uploads": (1, 64),
    "kept_upload_mib": (256, 8192),  # at least one upload of the largest size
    "kept_maps": (1, 64),
    "job_cost": (100.0, 1e6),
    "slice_s": (0.1, 60.0),
}

#: The caps of a studio given none.
DEFAULT_LIMITS = StudioLimits()

__all__ = ["BOUNDS", "DEFAULT_LIMITS", "StudioLimitError", "StudioLimits"]
