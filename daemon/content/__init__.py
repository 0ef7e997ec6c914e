"""What the display shows: content through the calibrated tables.

Roles: :mod:`.packets` (E1.31 and ArtDmx decoding), :mod:`.merge` (several senders into one
frame), :mod:`.receiver` (the UDP receivers), :mod:`.pixel_order` (channels onto pixels),
:mod:`.pictures` (files and animations), :mod:`.colour_map` (a picture's colours to levels
through the calibration), :mod:`.player` (the sources' priority and the frames at ``fps``),
:mod:`.sink` (the seam to the controllers' frame output), :mod:`.status` (what status
shows). The feature joins the service through :mod:`.feature`. Its ``[content]`` section is
:mod:`grassd.daemon.config.content` and ``grassd show`` is :mod:`grassd.daemon.cli.show`:
the feature imports the configuration and is imported by the CLI, never the other way round
(the daemon's subpackages import each other one way).
"""
