"""Taichi grass-pixel renderer: scene + light + viewpoint -> linear Rec.709 RGB measurements.

Never imports ``grassd.calib``, ``grassd.firmware_proto`` or ``grassd.daemon``. Importing this
package does not initialise Taichi; call :func:`grassd.sim.backend.init` at the program's entry.
"""
