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
* The C firmware (``firmware/`` in the source tree): :mod:`.native_build` builds it;
  :mod:`.posix_bus` runs its posix port, :mod:`.qemu_bus` its Cortex-M7 image under QEMU, as
  buses like :class:`~.simulator.SimulatedBus`; :mod:`.sim_backends` picks model, posix or
  qemu by name; :mod:`.power_cut` sweeps a power cut over every storage write of an update.
* :mod:`.errors` - :class:`~.errors.ProtocolError`; :class:`~.errors.TransientError` means
  retrying may help.
"""
