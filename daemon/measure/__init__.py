"""``grassd measure``: the display photographed under test patterns, each pixel's departure from
the model found, and per-pixel tables that include the correction.

Roles: :mod:`.patterns` (test patterns on the controllers), :mod:`.camera_chain` (the measuring
camera's shots and colour chain), :mod:`.run` (one measurement, start to verdict),
:mod:`grassd.daemon.runtime.measurement` runs one in the daemon and keeps what it found;
:mod:`grassd.daemon.monitoring.measurement_report` writes its report (JSON, HTML) and the trend.
The per-pixel model and correction live with the calibration they feed
(:mod:`grassd.daemon.calibration.pixel_model`, :mod:`grassd.daemon.calibration.variation`,
:mod:`grassd.daemon.calibration.correction`).
"""
