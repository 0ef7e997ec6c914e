"""The core: all that ``grassd run`` needs to turn a light bundle into tables on controllers.

It reads top to bottom: :mod:`.config` (the core sections of the configuration and the one
validator of documents users write), :mod:`.store` (the inbox with its bundles and manifests,
the state database, atomic writes), :mod:`.calibration` (one calibration pipeline for every
run, the display model, the correction a measurement saved), :mod:`.hardware` (the controllers
as one fleet, the lux sensor, the cameras' OSC client and bracket), :mod:`.runtime` (the main
loop, commit, reconcile, the control socket) and :mod:`.monitoring` (status, health, metrics,
alerts, the status page, journald logging). :mod:`.errors` holds the exception types of every
part, :mod:`.safe_text` makes a name from outside safe for one line.

The features (``capture``, ``measure``, ``compute``, ``content``) and the tools (``studio``,
``offline``) live beside it and import it; it imports no tool, and a feature only where
``tests/test_import_graph.py`` still names the edge.
"""
