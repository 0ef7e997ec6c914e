"""The ambient illuminance (lux) of a run: the manifest's ``ambient_lux`` when it has one,
else a reading of the Modbus lux sensor when ``[light] lux = "modbus"`` configures one."""

from __future__ import annotations

from collections.abc import Callable

from grassd.daemon.core.config.settings import LightConfig
from grassd.daemon.core.errors import LuxSensorError
from grassd.daemon.core.hardware.luxsensor import LuxSensor


def resolve_lux(manifest_lux: float | None, light: LightConfig, sensor: LuxSensor | None,
                progress: Callable[[str], None]) -> tuple[float, str]:
    """(ambient illuminance in lux, its source "manifest" or "modbus"): ``manifest_lux``
    when given, else a reading of ``sensor`` (``progress`` is told before it is read). Raises
    :class:`~grassd.daemon.core.errors.LuxSensorError` when there is neither, and the sensor's
    errors (:class:`~grassd.daemon.core.errors.LuxSensorUnreachable`, ``LuxSensorSilent``, ...)
    when the reading fails."""
    if manifest_lux is not None:
        return manifest_lux, "manifest"
    if light.lux != "modbus" or sensor is None:
        raise LuxSensorError("the manifest has no ambient_lux and no Modbus lux sensor is "
                             "configured (set [light] lux = \"modbus\" and [light.modbus])")
    progress("reading the lux sensor")
    return sensor.read_lux(), "modbus"
