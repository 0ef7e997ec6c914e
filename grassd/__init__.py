"""grassd: calibration daemon for grass displays.

The distribution maps five top-level folders onto sub-packages:
``calib/`` -> ``grassd.calib``, ``sim/`` -> ``grassd.sim``,
``firmware_proto/`` -> ``grassd.firmware_proto``, ``rigs/`` -> ``grassd.rigs`` (test rigs and
simulated hardware), ``daemon/`` -> ``grassd.daemon``.
Dependencies point one way: daemon -> {sim, calib, firmware_proto}; rigs are imported only by
the simulated-hardware entry points, tests and benchmarks (tests/test_import_graph.py).
"""

__version__ = "0.1.0"
