"""What the display shows: content through the calibrated tables.

Roles: :mod:`.config` (the ``[content]`` section), :mod:`.packets` (E1.31 and ArtDmx
decoding), :mod:`.merge` (several senders into one frame), :mod:`.receiver` (the UDP
receivers), :mod:`.pixel_order` (channels onto pixels), :mod:`.pictures` (files and
animations), :mod:`.colour_map` (a picture's colours to levels through the calibration),
:mod:`.player` (the sources' priority and the frames at ``fps``), :mod:`.sink` (the seam to
the controllers' frame output), :mod:`.status` (what status shows). The feature joins the
service through :mod:`.feature`; ``grassd show`` lives in :mod:`.cli`.
"""
