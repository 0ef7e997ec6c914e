"""The grass-display controller wire protocol: spec, codec, client and simulated controllers.

Never imports ``grassd.calib``, ``grassd.sim`` or ``grassd.daemon``. See PROTOCOL.md.
"""
