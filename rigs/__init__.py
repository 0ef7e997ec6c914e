"""Test rigs and simulated hardware: what stands in for the site, never what runs on it.

``grassd.rigs`` holds the code that imitates or exercises the hardware a real ``grassd run``
talks to. It ships with the distribution because three product commands serve simulated
hardware (``grassd run --simulate-hardware``, ``grassd demo`` / ``make demo`` and
``grassd controllers sim``), but no code path that drives a real display needs it.

Simulated hardware (the controllers behind ``--simulate-hardware``, ``demo`` and
``controllers sim``):

* :mod:`.firmware` - the Python model of a controller (the reference the C firmware in
  ``firmware/`` implements); :mod:`.eeprom` - its file-backed EEPROM and two-bank store;
  :mod:`.faults` - fault injection on its line; :mod:`.pty_line` - pseudo-terminal lines;
  :mod:`.simulator` - model controllers on a pty (:class:`~.simulator.SimulatedBus`).
* :mod:`.native_build` builds the C firmware; :mod:`.posix_bus` runs its posix port,
  :mod:`.qemu_bus` its Cortex-M7 image under QEMU, as buses like the simulator's;
  :mod:`.sim_backends` picks model, posix or qemu by name (:data:`FIRMWARE_BACKENDS`).

Test and benchmark rigs:

* :mod:`.golden` - builds and loads the protocol's golden vectors (the files stay in
  ``firmware_proto/vectors/``, next to PROTOCOL.md); :mod:`.loopback` - an in-process line to
  model controllers; :mod:`.push_audit` - pushes checked against the controller's RAM and
  EEPROM; :mod:`.power_cut` - a power cut at every storage write of an update;
  :mod:`.mitsuba_scene` - Mitsuba 3 as an independent reference renderer; :mod:`.processes` -
  child processes (a firmware port, QEMU, a daemon, a studio) ended as a service manager ends
  them; :mod:`.dask_cluster` - a Dask scheduler and workers on 127.0.0.1 with a site CA of
  their own, and the preload that turns a worker hostile.
* A world grassd did not render: :mod:`.spectral_camera` - a camera defined by its spectral
  sensitivities; :mod:`.spectral_world` - an exported pixel in Mitsuba's spectral light,
  photographed for ``grassd validate`` and ``grassd fit``; :mod:`.spectral_display` - the
  whole display so, as ``grassd measure``'s camera photographs it.

The rule (``tests/test_import_graph.py``): no module of ``grassd.calib``, ``grassd.sim``,
``grassd.firmware_proto`` or ``grassd.daemon`` imports a module of this package, lazily or
not, except the entry points that serve simulated hardware:

* the command-line modules that serve simulated hardware, each inside the commands or the
  ``--simulate-hardware`` path that use it: ``grassd.daemon.cli.run`` (the simulated site of
  ``grassd run --simulate-hardware`` and ``grassd demo``: :mod:`.simulated_site`, whose
  controllers, lux sensor and cameras are :mod:`.simulated_display` and
  :mod:`.simulated_camera`), ``grassd.daemon.cli.controllers`` (``grassd controllers sim``),
  ``grassd.daemon.capture.cli`` (``grassd camera sim``) and ``grassd.daemon.measure.cli``
  (``grassd measure --simulate-hardware``).

Tests and benchmarks import anything here. This ``__init__`` imports nothing and only names the
choices and defaults of those commands (firmware backends, the simulated camera's response
curves, capture modes and defaults), so that the command line can offer them without loading a
rig: importing ``grassd.rigs`` itself is allowed everywhere in the daemon.
"""

#: Firmware backends a simulated bus can run, the first being the default
#: (:func:`~.sim_backends.open_bus`).
FIRMWARE_BACKENDS = ("model", "posix", "qemu")

#: The simulated camera's response curves (:data:`~.simulated_camera.CURVES`) and OSC capture
#: modes (:class:`~.simulated_camera.CaptureMode`).
SIM_CAMERA_CURVES = ("gamma22", "filmic", "soft")
SIM_CAMERA_CAPTURE_MODES = ("image", "video")
#: Defaults of ``grassd camera sim`` (and of :class:`~.simulated_camera.SimCamera`): the largest
#: panorama width served (texels; a wider map is downsampled by whole factors), the response
#: curve (one of :data:`SIM_CAMERA_CURVES`) and the light level (cd/m^2 per map unit).
SIM_CAMERA_WIDTH = 512
SIM_CAMERA_CURVE = "filmic"
SIM_CAMERA_SCENE_SCALE = 1000.0
