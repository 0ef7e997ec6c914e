"""The features ``grassd run`` joins to the service (each in its own folder, joined through
:class:`~grassd.daemon.core.runtime.features.Feature`), in the order they start: the capture
station, measurements, content, and compute offload (the calibrator on a Dask cluster)."""

from __future__ import annotations

from grassd.daemon.core.runtime.features import Feature


def daemon_features() -> list[Feature]:
    """A fresh instance of every feature of the daemon (each reads its own config section and
    runs nothing without it)."""
    from grassd.daemon.capture.feature import CaptureFeature
    from grassd.daemon.compute.feature import ComputeFeature
    from grassd.daemon.content.feature import ContentFeature
    from grassd.daemon.measure.feature import MeasureFeature

    return [CaptureFeature(), MeasureFeature(), ContentFeature(), ComputeFeature()]
