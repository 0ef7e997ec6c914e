"""The capture station as it joins the daemon (:class:`~grassd.daemon.core.runtime.features
.Feature`): its loop started with the daemon, replaced when a reload changes ``[capture]``, the
inbox or the lux sensor, and its summary under ``capture`` in the status."""

from __future__ import annotations

from typing import TYPE_CHECKING

from grassd.daemon.core.runtime.features import Feature

if TYPE_CHECKING:
    from grassd.daemon.capture.station import CaptureLoop, CaptureSummary
    from grassd.daemon.core.config.settings import Config
    from grassd.daemon.core.runtime.service import Service


class CaptureFeature(Feature):
    """The capture station's thread (:func:`~grassd.daemon.capture.station.start_capture_loop`)
    for the daemon's ``[capture]``; none without it. Its own thread: a capture never blocks or
    delays a calibration, and a replaced loop finishes its capture in the background before
    the new one starts."""

    name = "capture"

    def __init__(self) -> None:
        #: the station's loop now, None without ``[capture]``
        self.loop: CaptureLoop | None = None

    def restart(self, svc: Service, old: Config | None) -> None:
        """Start the loop for ``svc.cfg``, or replace it when ``[capture]``, the inbox or
        the lux sensor changed since ``old``."""
        new = svc.cfg
        if old is not None and (new.capture, new.light.inbox, new.light.modbus) == (
                old.capture, old.light.inbox, old.light.modbus):
            return
        before = self.loop
        if before is not None:
            before.stop(timeout_s=None)
        self.loop = None
        if new.capture is not None:
            from grassd.daemon.capture.station import start_capture_loop

            self.loop = start_capture_loop(new, after=before)

    def stop(self) -> None:
        """Stop the loop (its capture in flight ends first, within its own deadline)."""
        if self.loop is not None:
            self.loop.stop()

    def status(self) -> CaptureSummary | None:
        """The loop's summary (:meth:`~grassd.daemon.capture.station.CaptureLoop.summary`)."""
        return None if self.loop is None else self.loop.summary()

    def last_success_at(self) -> float | None:
        """When the station last delivered a bundle (epoch s)."""
        return None if self.loop is None else self.loop.last_success_at
