"""``grassd measure``: the display photographed under test patterns, each pixel's departure from
the model found, and per-pixel tables that include the correction.

Roles: :mod:`.config` (``[measure]``), :mod:`.patterns` (test patterns on the controllers),
:mod:`.camera_chain` (the measuring camera's shots and colour chain), :mod:`.pixel_model` (the
per-pixel model fitted to the shots), :mod:`.evidence` (what the photos show and whether it
is enough), :mod:`.run` (one measurement, start to verdict), :mod:`.job` (one measurement in
the daemon: the display held, what it found kept), :mod:`.report` (its report, JSON and HTML,
and the trend) and :mod:`.cli` (``grassd measure``). The variation and correction it saves are
the core's (:mod:`grassd.daemon.core.calibration.variation`,
:mod:`grassd.daemon.core.calibration.correction`): every run's tables include them.
"""
