"""The capture station: an Open Spherical Camera and a lux sensor make light bundles by
themselves (``grassd capture``, the ``[capture]`` config section, ``grassd camera sim``).

Modules: :mod:`.osc_client` (the camera over HTTP/JSON), :mod:`.bracket` (an exposure bracket
with each shot's real exposure), :mod:`.camera_sim` (a simulated OSC camera photographing a
known HDRI), :mod:`.settings` (the ``[capture]`` section), :mod:`.station` (bracket -> merged
EXR + lux -> bundle in the inbox, once or on a schedule), :mod:`.errors`.
"""
