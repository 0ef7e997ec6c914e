"""The grass-display controller wire protocol: spec, codec, client and simulated controllers.

Never imports ``grassd.calib``, ``grassd.sim`` or ``grassd.daemon``. See PROTOCOL.md.

Modules, from the wire up:

* :mod:`.crc` - CRC-32/ISO-HDLC; :mod:`.framing` - COBS frames, :class:`~.framing.FrameReader`;
  :mod:`.messages` - message values and payloads; :mod:`.codec` - whole frames (pure);
  :mod:`.tables` - length tables <-> bytes; :mod:`.table_file` - JSON/CSV table files.
* :mod:`.link` - frames over a pyserial port (exception boundary); :mod:`.client` -
  :class:`~.client.ControllerClient` and :func:`~.client.push_table`,
  :func:`~.client.read_status`, :func:`~.client.hello`, :func:`~.client.scan`.
* :mod:`.eeprom` - file-backed EEPROM and the two-bank store; :mod:`.firmware` - the
  controller state machine; :mod:`.faults` - fault injection; :mod:`.simulator` - controllers
  on ptys; :mod:`.golden` - the test vectors in ``vectors/``.
* :mod:`.errors` - :class:`~.errors.ProtocolError`; :class:`~.errors.TransientError` means
  retrying may help.
"""
