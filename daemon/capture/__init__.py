"""The capture station: a 360-degree camera brings the light in. :mod:`.station` takes a bracket
with the OSC camera, merges it and drops a light bundle into the inbox (in the daemon, on a
thread of its own, at ``[capture] interval_s``); :mod:`.cli` is ``grassd capture`` and
``grassd camera sim``. The camera's client, its bracket and the ``[capture]`` section are
:mod:`grassd.daemon.camera`'s, which ``measure`` shares: its measuring camera is the same kind
of device."""
