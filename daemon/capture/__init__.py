"""The capture station: a 360-degree camera brings the light in. :mod:`.station` takes a bracket
with the OSC camera, merges it and drops a light bundle into the inbox (in the daemon, on a
thread of its own, at ``[capture] interval_s``); :mod:`.cli` is ``grassd capture`` and
``grassd camera sim``. The camera's client, its bracket and the ``[capture]`` section are the
core's (:mod:`grassd.daemon.core.hardware.camera`, :mod:`grassd.daemon.core.hardware.bracket`,
:mod:`grassd.daemon.core.config.camera_section`): the measuring camera of ``measure`` is the
same kind of device."""
