"""The input of a scheduled run (``schedule.interval_s``, or a ``calibrate`` request): there is
no new bundle, so the light is that of the last archived bundle (or the embedded default
site when there is none or it is unusable), stamped now, and the lux comes from the sensor
when one is configured, else from that bundle."""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass
from datetime import UTC, datetime

from grassd.daemon.core.errors import DaemonError
from grassd.daemon.core.store.history import History
from grassd.daemon.core.store.ingest import Inbox
from grassd.sim.light_input import LightInput

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class ScheduledInput:
    """What a scheduled run calibrates for: ``light`` (with the ambient lux), the hashes of its
    inputs, the lux (lx) and its source ("manifest" or "modbus"), and the light capture time
    (epoch s) of the bundle it came from (None for the embedded default site)."""

    light: LightInput
    input_hashes: dict[str, str]
    lux: float
    lux_source: str
    light_at: float | None


def scheduled_input(history: History, inbox: Inbox, sensor_first: bool,
                    lux: Callable[[float | None], tuple[float, str]]) -> ScheduledInput:
    """The input of a scheduled run (see the module docstring). ``sensor_first``: a lux sensor
    is configured and its reading wins over the bundle's ``ambient_lux``; ``lux(manifest_lux)``
    gives (lux, source) as :func:`~grassd.daemon.core.runtime.ambient_lux.resolve_lux`. Raises
    :class:`~grassd.daemon.core.errors.DaemonError` when no lux can be had (the run is skipped)."""
    last = history.latest_archived()
    manifest = None
    if last is not None:
        try:
            manifest = inbox.archived_manifest(last.bundle_id)
        except DaemonError as exc:
            log.warning("last archived bundle %s unusable: %s", last.bundle_id, exc)
    light_at = None if manifest is None else manifest.timestamp.timestamp()
    if manifest is not None:
        ambient, source = lux(None if sensor_first else manifest.light.ambient_lux)
        light = LightInput(hdri=manifest.light.hdri, ambient_lux=ambient,
                           timestamp=datetime.now(UTC))
        hashes = {"bundle": last.bundle_hash}
    else:
        from grassd.sim.hdri import default_site_hdri

        ambient, source = lux(None)
        light = LightInput(hdri=default_site_hdri(), ambient_lux=ambient,
                           timestamp=datetime.now(UTC))
        hashes = {"hdri": "embedded default_site.exr"}
    return ScheduledInput(light, hashes, ambient, source, light_at)
