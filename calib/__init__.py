"""Colour science for grassd: captures, colour correction, CIELAB/CIEDE2000, OGCD, length tables.

Never imports ``grassd.sim``, ``grassd.firmware_proto`` or ``grassd.daemon``.
"""
