"""The Open Spherical Camera that the capture station and measure both use: its ``[capture]``
config section (:mod:`~grassd.daemon.camera.config`), the messages it speaks
(:mod:`~grassd.daemon.camera.messages`), the client that talks to it over HTTP and trusts none
of its answers (:mod:`~grassd.daemon.camera.client`) and the exposure bracket it shoots
(:mod:`~grassd.daemon.camera.bracket`). Not part of the core: turning a bundle into tables
needs no camera. It imports only the core; the features that photograph import it."""
