"""The grass-display controller wire protocol: spec, codec and the host's client.

Never imports ``grassd.calib``, ``grassd.sim``, ``grassd.daemon`` or ``grassd.rigs``. See
PROTOCOL.md; ``vectors/*.json`` are its golden vectors (built and loaded by
:mod:`grassd.rigs.golden`, replayed by the C firmware's tests).

Modules, from the wire up:

* :mod:`.crc` - CRC-32/ISO-HDLC; :mod:`.framing` - COBS frames, :class:`~.framing.FrameReader`;
  :mod:`.messages` - message values and payloads; :mod:`.codec` - whole frames (pure);
  :mod:`.tables` - length tables <-> bytes; :mod:`.table_file` - JSON/CSV table files.
* :mod:`.link` - frames over a pyserial port (exception boundary); :mod:`.line_quality` - the
  line's error rate and the chunk size it allows; :mod:`.client` -
  :class:`~.client.ControllerClient` and :func:`~.client.push_table`,
  :func:`~.client.read_status`, :func:`~.client.hello`, :func:`~.client.scan`.
* :mod:`.errors` - :class:`~.errors.ProtocolError`; :class:`~.errors.TransientError` means
  retrying may help.

The controller's side (the Python model of the firmware, its EEPROM, simulated buses, the C
firmware's posix and QEMU buses, fault injection) is simulated hardware and lives in
:mod:`grassd.rigs`.
"""
