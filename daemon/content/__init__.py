"""What the display shows: content through the calibrated tables.

Roles: :mod:`.packets` (E1.31 and ArtDmx decoding), :mod:`.merge` (several senders into one
frame), :mod:`.receiver` (the UDP receivers), :mod:`.pixel_order` (channels onto pixels),
:mod:`.pictures` (files and animations), :mod:`.colour_map` (a picture's colours to levels
through the calibration), :mod:`.player` (the sources' priority and the frames at ``fps``),
:mod:`.sink` (the seam to the controllers' frame output), :mod:`.status` (what status
shows), :mod:`.frames` (the newest frame staged on every controller and shown together by a
broadcast SHOW), :mod:`.shown` and :mod:`.display_picture` (the display as its controllers
report it, for the status page), :mod:`.config` (``[content]``) and :mod:`.cli`
(``grassd show``). The feature joins the service through :mod:`.feature`.
"""
