"""grassd: calibration daemon for grass displays.

The distribution maps four top-level folders onto sub-packages:
``calib/`` -> ``grassd.calib``, ``sim/`` -> ``grassd.sim``,
``firmware_proto/`` -> ``grassd.firmware_proto``, ``daemon/`` -> ``grassd.daemon``.
Dependencies point one way: daemon -> {sim, calib, firmware_proto} (tests/test_import_graph.py).
"""

__version__ = "0.1.0"
