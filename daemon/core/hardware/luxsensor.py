"""Read ambient illuminance (lux) from a Modbus RTU or TCP lux sensor (pymodbus client).

Real sensors differ in where and how they store the reading, so the register map is
configuration (:class:`~grassd.daemon.core.config.settings.ModbusConfig`): function code 3 (holding)
or 4 (input registers), start register, 1 or 2 words, word order for 32-bit values ("big" = high
word first), value type (unsigned / signed integer, IEEE-754 float32 in two words), and ``lux =
scale * value + offset``.

Errors are typed: :class:`~grassd.daemon.core.errors.LuxSensorUnreachable` when no connection can be
opened (TCP refused, serial port missing), :class:`~grassd.daemon.core.errors.LuxSensorSilent` when
the sensor does not answer in time or answers with a Modbus exception, and
:class:`~grassd.daemon.core.errors.LuxSensorError` when it answers with a Modbus exception (wrong
unit, register or function code: not retried) or a reading that is not a usable illuminance.
Unreachable and silent attempts are retried ``retries`` times with a short backoff.

An RS-485 (RTU) bus has one master: every :class:`LuxSensor` on one serial port in this process
(the daemon's, kept open, and the capture station's shaded and unshaded one-shot reads) shares
one client and takes its transactions one at a time (:class:`_RtuBus`). A serial port opened a
second time fails, and two requests on the line at once garble both answers.
"""

from __future__ import annotations

import contextlib
import logging
import math
import struct
import threading
import time
from collections.abc import Sequence

from pymodbus.client import ModbusSerialClient, ModbusTcpClient
from pymodbus.exceptions import ConnectionException, ModbusException, ModbusIOException

from grassd.daemon.core.config.settings import ModbusConfig
from grassd.daemon.core.errors import LuxSensorError, LuxSensorSilent, LuxSensorUnreachable
from grassd.sim.lighting import MAX_LUX

log = logging.getLogger(__name__)
logging.getLogger("pymodbus").setLevel(logging.CRITICAL)  # we report failures ourselves


def decode_registers(registers: Sequence[int], cfg: ModbusConfig) -> float:
    """Turn raw 16-bit ``registers`` into lux per the register map ``cfg``.

    >>> from grassd.daemon.core.config.settings import load_default_config
    >>> cfg = load_default_config().light.modbus       # 2 words, big word order, uint, x0.1
    >>> decode_registers([0x0001, 0x0000], cfg)          # 65536 counts * 0.1 lux
    6553.6
    """
    regs = [int(r) & 0xFFFF for r in registers]
    if len(regs) != cfg.words:
        raise LuxSensorError(f"expected {cfg.words} register(s) from the lux sensor, got "
                             f"{len(regs)}")
    if cfg.words == 2 and cfg.word_order == "little":
        regs = regs[::-1]
    raw = struct.pack(">" + "H" * len(regs), *regs)
    if cfg.value_type == "float":
        value = struct.unpack(">f", raw)[0]
    elif cfg.value_type == "int":
        value = struct.unpack(">h" if cfg.words == 1 else ">i", raw)[0]
    else:
        value = struct.unpack(">H" if cfg.words == 1 else ">I", raw)[0]
    return float(value) * cfg.scale + cfg.offset


def encode_lux(lux: float, cfg: ModbusConfig) -> list[int]:
    """Inverse of :func:`decode_registers`: the registers a sensor would hold for ``lux``."""
    value = (lux - cfg.offset) / cfg.scale
    if cfg.value_type == "float":
        raw = struct.pack(">f", value)
    else:
        n = round(value)
        fmt = {("int", 1): ">h", ("int", 2): ">i", ("uint", 1): ">H", ("uint", 2): ">I"}
        raw = struct.pack(fmt[(cfg.value_type, cfg.words)], n)
    regs = list(struct.unpack(">" + "H" * cfg.words, raw))
    if cfg.words == 2 and cfg.word_order == "little":
        regs = regs[::-1]
    return regs


class _RtuBus:
    """The Modbus RTU client of one serial port, shared by every :class:`LuxSensor` on it in
    this process (``users`` of them), with the lock that keeps one transaction on the bus."""

    _open: dict[str, _RtuBus] = {}
    _guard = threading.Lock()

    def __init__(self, cfg: ModbusConfig) -> None:
        self.client = ModbusSerialClient(cfg.serial_port, baudrate=cfg.baud,
                                         timeout=cfg.timeout_s, retries=0)
        self.lock = threading.RLock()
        self.users = 0

    @classmethod
    def join(cls, cfg: ModbusConfig) -> _RtuBus:
        """The bus of ``cfg.serial_port``, opened by its first user (its baud rate and timeout
        hold for all: one bus, one line speed)."""
        with cls._guard:
            bus = cls._open.get(cfg.serial_port)
            if bus is None:
                bus = cls._open[cfg.serial_port] = cls(cfg)
            bus.users += 1
            return bus

    def leave(self, port: str) -> None:
        """One user less; the last one closes the port."""
        with self._guard, self.lock:
            self.users -= 1
            if self.users <= 0:
                self.client.close()
                self._open.pop(port, None)


class LuxSensor:
    """A Modbus lux sensor described by ``cfg``; :meth:`read_lux` returns lux.

    The connection is opened lazily and reopened after errors; use as a context manager or call
    :meth:`close`.
    """

    def __init__(self, cfg: ModbusConfig) -> None:
        self.cfg = cfg
        self._client: ModbusTcpClient | ModbusSerialClient | None = None
        self._bus: _RtuBus | None = None  # RTU: the port's shared client and lock
        #: outcome of the last :meth:`read_lux` (None: none yet) and when the sensor last gave
        #: a reading (epoch s), for the operator's metrics
        self.last_ok: bool | None = None
        self.last_success_at: float | None = None

    @property
    def endpoint(self) -> str:
        """Human-readable address of the sensor."""
        c = self.cfg
        where = f"tcp {c.host}:{c.port}" if c.mode == "tcp" else f"rtu {c.serial_port}@{c.baud}"
        return f"{where} unit {c.unit}"

    def _make_client(self) -> ModbusTcpClient | ModbusSerialClient:
        c = self.cfg
        if c.mode == "tcp":
            return ModbusTcpClient(c.host, port=c.port, timeout=c.timeout_s, retries=0)
        self._bus = _RtuBus.join(c)
        return self._bus.client

    def close(self) -> None:
        """Close the connection (reopened by the next read); on a shared RTU bus, the port
        closes with its last user."""
        if self._bus is not None:
            self._bus.leave(self.cfg.serial_port)
        elif self._client is not None:
            self._client.close()
        self._client, self._bus = None, None

    def _reset(self) -> None:
        """After a failed request: drop the connection, so that the next request opens it
        afresh (on an RTU bus, for every sensor on it; called holding the bus's lock)."""
        if self._bus is not None:
            self._bus.client.close()
        else:
            self.close()

    def _transaction(self) -> contextlib.AbstractContextManager:
        """Held for one request and its answer: the RTU bus's lock (TCP: nothing)."""
        return self._bus.lock if self._bus is not None else contextlib.nullcontext()

    def __enter__(self) -> LuxSensor:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _read_once(self) -> list[int]:
        if self._client is None:
            self._client = self._make_client()
        with self._transaction():
            return self._request()

    def _request(self) -> list[int]:
        c = self.cfg
        assert self._client is not None
        if not self._client.connected and not self._client.connect():
            self._reset()
            raise LuxSensorUnreachable(
                f"lux sensor at {self.endpoint} is unreachable (connection refused or port "
                "missing): check [light.modbus] host/port or serial_port, wiring and power")
        read = (self._client.read_holding_registers if c.function_code == 3
                else self._client.read_input_registers)
        try:
            resp = read(c.register, count=c.words, device_id=c.unit)
        except ConnectionException as exc:
            self._reset()
            raise LuxSensorUnreachable(f"lux sensor at {self.endpoint} dropped the connection: "
                                       f"{exc}") from None
        except ModbusIOException:
            self._reset()
            raise LuxSensorSilent(
                f"lux sensor at {self.endpoint} did not answer within {c.timeout_s:g} s: check "
                "unit id, baud rate and A/B wiring") from None
        except ModbusException as exc:
            self._reset()
            raise LuxSensorSilent(f"lux sensor at {self.endpoint} failed: {exc}") from None
        if resp.isError():
            code = getattr(resp, "exception_code", "?")
            raise LuxSensorError(
                f"lux sensor at {self.endpoint} answered Modbus exception {code} for function "
                f"{c.function_code} register {c.register} x{c.words}: check the register map")
        regs = list(resp.registers)
        if len(regs) != c.words:
            raise LuxSensorError(f"lux sensor at {self.endpoint} returned {len(regs)} registers,"
                                 f" expected {c.words}")
        return regs

    def read_lux(self) -> float:
        """Read the illuminance in lux (retrying ``cfg.retries`` times with 0.1-0.8 s backoff)."""
        last: LuxSensorError | None = None
        self.last_ok = False
        for attempt in range(self.cfg.retries + 1):
            if attempt:
                time.sleep(min(0.1 * 2 ** (attempt - 1), 0.8))
            try:
                regs = self._read_once()
            except (LuxSensorUnreachable, LuxSensorSilent) as exc:
                last = exc
                log.debug("lux read attempt %d failed: %s", attempt + 1, exc)
                continue
            lux = decode_registers(regs, self.cfg)
            if not math.isfinite(lux) or not 0 < lux <= MAX_LUX:
                raise LuxSensorError(f"lux sensor at {self.endpoint} reads {lux:g} lux, which is "
                                     "not a usable illuminance: check scale, offset, value_type "
                                     "and word_order")
            self.last_ok, self.last_success_at = True, time.time()
            return lux
        assert last is not None
        n = self.cfg.retries + 1
        raise type(last)(f"{last} (after {n} attempt{'s' if n > 1 else ''})")


def read_lux(cfg: ModbusConfig) -> float:
    """One-shot: open, read the illuminance (lux), close."""
    with LuxSensor(cfg) as sensor:
        return sensor.read_lux()
