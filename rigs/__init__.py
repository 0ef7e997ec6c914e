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
  them.

The rule (``tests/test_import_graph.py``): no module of ``grassd.calib``, ``grassd.sim``,
``grassd.firmware_proto`` or ``grassd.daemon`` imports a module of this package, lazily or
not, except the entry points that serve simulated hardware:

* ``grassd.daemon.hardware.simulated`` - the simulated site (controllers, lux sensor) of
  ``grassd run --simulate-hardware`` and ``grassd demo``; the rest of the daemon imports it
  only inside functions, on the ``--simulate-hardware`` path;
* ``grassd.daemon.cli.controllers`` - ``grassd controllers sim``, inside that command only.

Tests and benchmarks import anything here. This ``__init__`` imports nothing and only names the
firmware backends, so that the command line can offer ``--sim-firmware`` / ``--firmware``
without loading a rig: importing ``grassd.rigs`` itself is allowed everywhere in the daemon.
"""

#: Firmware backends a simulated bus can run, the first being the default
#: (:func:`~.sim_backends.open_bus`).
FIRMWARE_BACKENDS = ("model", "posix", "qemu")
