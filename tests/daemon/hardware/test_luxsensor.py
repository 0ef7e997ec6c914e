"""Modbus lux sensor client against a real pymodbus server (TCP on 127.0.0.1, RTU on ptys)."""

from __future__ import annotations

import dataclasses
import socket
import time

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from grassd.daemon.core.config.settings import load_default_config
from grassd.daemon.core.errors import LuxSensorError, LuxSensorSilent, LuxSensorUnreachable
from grassd.daemon.core.hardware.luxsensor import LuxSensor, decode_registers, encode_lux, read_lux
from grassd.rigs.simulated_site import SimLuxSensor

BASE = load_default_config().light.modbus


def cfg(**kw):
    return dataclasses.replace(BASE, **kw)


@pytest.mark.parametrize(
    ("kw", "lux"),
    [
        ({"words": 1, "value_type": "uint", "scale": 1.0}, 850.0),
        ({"words": 2, "value_type": "uint", "word_order": "big", "scale": 0.1}, 98765.4),
        ({"words": 2, "value_type": "uint", "word_order": "little", "scale": 0.01}, 1234.56),
        ({"words": 2, "value_type": "float", "word_order": "little", "scale": 1.0}, 31.25),
        ({"words": 2, "value_type": "int", "scale": 1.0, "offset": 10.0}, 510.0),
        ({"words": 1, "value_type": "uint", "register": 7, "function_code": 3, "unit": 5,
          "scale": 2.0}, 4000.0),
    ],
)
def test_tcp_register_maps(kw, lux):
    with SimLuxSensor(cfg(**kw), lux) as sensor:
        got = read_lux(sensor.config)
    assert got == pytest.approx(lux, rel=1e-6)


def test_word_order_matters():
    regs = encode_lux(98765.4, cfg(word_order="big"))
    assert regs == [0x000F, 0x1206]  # 987654 counts, high word first
    assert decode_registers(regs, cfg(word_order="little")) == pytest.approx(
        0x1206000F * 0.1)


@settings(max_examples=200, deadline=None)
@given(lux=st.floats(0.01, 100_000), order=st.sampled_from(["big", "little"]),
       vt=st.sampled_from(["uint", "int", "float"]))
def test_encode_decode_roundtrip(lux, order, vt):
    c = cfg(word_order=order, value_type=vt, words=2, scale=0.01)
    assert decode_registers(encode_lux(lux, c), c) == pytest.approx(lux, abs=0.006, rel=1e-6)


def test_sensor_follows_changes_and_reuses_connection():
    with SimLuxSensor(BASE, 100.0) as sim, LuxSensor(sim.config) as client:
        seen = []
        for lux in (100.0, 5000.0, 120000.0):
            sim.lux = lux
            seen.append(client.read_lux())
        assert seen == pytest.approx([100.0, 5000.0, 120000.0])
        assert sim.reads == 3


def test_unreachable_tcp_is_typed_and_retried():
    with socket.socket() as s:  # a port with nobody listening
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    t0 = time.monotonic()
    with pytest.raises(LuxSensorUnreachable, match=rf"127\.0\.0\.1:{port}.*after 3 attempts"):
        read_lux(cfg(port=port, retries=2))
    assert time.monotonic() - t0 >= 0.3  # backoff 0.1 + 0.2 s between the attempts


def test_silent_sensor_times_out():
    with SimLuxSensor(BASE, 100.0) as sim:
        sim.silent = True
        t0 = time.monotonic()
        with pytest.raises(LuxSensorSilent, match=r"did not answer within 0\.2 s"):
            read_lux(dataclasses.replace(sim.config, timeout_s=0.2, retries=1))
        took = time.monotonic() - t0
        sim.silent = False
    assert 0.4 <= took < 3.0


def test_wrong_register_map_is_modbus_exception_not_retried():
    with SimLuxSensor(BASE, 100.0) as sim:
        with pytest.raises(LuxSensorError, match="Modbus exception 2.*register 40"):
            read_lux(dataclasses.replace(sim.config, register=40, retries=5))
        assert sim.reads == 0


def test_absurd_reading_is_refused():
    with SimLuxSensor(cfg(scale=1.0, words=1, value_type="int"), 0.0) as sim:
        with pytest.raises(LuxSensorError, match="not a usable illuminance"):
            read_lux(sim.config)


def test_rtu_over_null_modem_ptys():
    c = cfg(baud=19200, word_order="little", value_type="float", scale=1.0)
    with SimLuxSensor(c, 777.5, rtu=True) as sim:
        assert sim.config.mode == "rtu" and sim.config.serial_port.startswith("/dev/pts/")
        assert read_lux(sim.config) == 777.5
        sim.lux = 42.0
        assert read_lux(sim.config) == 42.0


def test_rtu_missing_port_is_unreachable(tmp_path):
    with pytest.raises(LuxSensorUnreachable, match="rtu"):
        read_lux(cfg(mode="rtu", serial_port=str(tmp_path / "ttyUSB9"), retries=0))


def test_rtu_bus_shared_by_two_readers_in_one_process():
    """The daemon's sensor (a connection kept open) and the capture station's one-shot reads
    share one RS-485 bus: a Modbus RTU bus has one master, so their transactions must not
    overlap. Two threads read 40 times each over the same null-modem pty; every reading is
    right and none times out."""
    import threading

    c = cfg(baud=115200, word_order="little", value_type="float", scale=1.0, timeout_s=0.5,
            retries=0)
    with SimLuxSensor(c, 777.5, rtu=True) as sim:
        errors: list[BaseException] = []
        readings: list[float] = []

        def reader(kept_open: bool) -> None:
            try:
                if kept_open:
                    with LuxSensor(sim.config) as sensor:
                        readings.extend(sensor.read_lux() for _ in range(40))
                else:
                    readings.extend(read_lux(sim.config) for _ in range(40))
            except BaseException as exc:  # noqa: BLE001 - reported by the assertion below
                errors.append(exc)

        threads = [threading.Thread(target=reader, args=(k,)) for k in (True, False)]
        for t in threads:
            t.start()
        for t in threads:
            t.join(60)
        assert not errors, errors
        assert readings == [777.5] * 80
