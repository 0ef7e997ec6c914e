"""Compute offload as it joins the daemon (:class:`~grassd.daemon.core.runtime.features
.Feature`): with ``[compute] scheduler``, the calibrator the service runs its calibrations with
is a :class:`~grassd.daemon.compute.remote.RemoteCalibrator` on that Dask cluster (and this
computer needs no Taichi for them); without it, the service's own."""

from __future__ import annotations

from typing import TYPE_CHECKING

from grassd.daemon.core.runtime.features import Feature

if TYPE_CHECKING:
    from grassd.daemon.core.calibration.calibrate import Calibrates
    from grassd.daemon.core.config.settings import Config


class ComputeFeature(Feature):
    """Offers the service a calibrator on the Dask cluster of ``[compute] scheduler``."""

    name = "compute"

    def calibrator(self, cfg: Config) -> Calibrates | None:
        """A :class:`~grassd.daemon.compute.remote.RemoteCalibrator` with ``[compute]
        scheduler`` (ConfigError when it is not secured as ``[compute]`` requires), else
        None."""
        if cfg.compute.scheduler is None:
            return None
        from grassd.daemon.compute.remote import RemoteCalibrator

        return RemoteCalibrator(cfg)
