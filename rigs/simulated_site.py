"""Simulated hardware for tests, demos and ``grassd run --simulate-hardware``.

:class:`SimLuxSensor` is a real pymodbus TCP server on 127.0.0.1 (its own thread and asyncio
loop) holding the lux value in the registers a
:class:`~grassd.daemon.core.config.settings.ModbusConfig` describes, in both the holding (FC 3) and
input (FC 4) register tables. It can be told to go silent (hold every request unanswered) to
exercise timeouts. With ``rtu=True`` it is a Modbus RTU server instead, on one end of a null-modem
made of two pseudo-terminals; the client opens the other end (:attr:`SimLuxSensor.config` names it),
exactly as it would a USB RS-485 adapter.
"""

from __future__ import annotations

import asyncio
import dataclasses
import logging
import os
import select
import threading
import tty
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import tomli_w
from pymodbus.constants import ExcCodes
from pymodbus.server import ModbusSerialServer, ModbusTcpServer
from pymodbus.simulator import DataType, SimData, SimDevice

from grassd.daemon.core.config.settings import Config, ModbusConfig
from grassd.daemon.core.hardware.luxsensor import encode_lux
from grassd.rigs.sim_backends import FIRMWARE_BACKENDS, open_bus

log = logging.getLogger(__name__)


class NullModem:
    """Two pseudo-terminals whose master sides are cross-connected by a relay thread.

    Whatever is written to :attr:`port_a` can be read from :attr:`port_b` and vice versa, like
    two serial ports joined by a null-modem cable.
    """

    def __init__(self) -> None:
        self._m1, self._s1 = os.openpty()
        self._m2, self._s2 = os.openpty()
        for fd in (self._s1, self._s2):
            tty.setraw(fd)
        self.port_a = os.ttyname(self._s1)
        self.port_b = os.ttyname(self._s2)
        self._stop_r, self._stop_w = os.pipe()
        self._thread = threading.Thread(target=self._relay, name="null-modem", daemon=True)
        self._thread.start()

    def _relay(self) -> None:
        peer = {self._m1: self._m2, self._m2: self._m1}
        while True:
            ready, _, _ = select.select([self._m1, self._m2, self._stop_r], [], [])
            if self._stop_r in ready:
                return
            for fd in ready:
                try:
                    data = os.read(fd, 4096)
                except OSError:
                    continue
                if data:
                    os.write(peer[fd], data)

    def close(self) -> None:
        """Stop the relay and close every descriptor."""
        os.write(self._stop_w, b"x")
        self._thread.join(2)
        for fd in (self._m1, self._s1, self._m2, self._s2, self._stop_r, self._stop_w):
            try:
                os.close(fd)
            except OSError:
                pass



class SimLuxSensor:
    """A Modbus/TCP lux sensor on ``host``:``port`` (port 0 = pick a free one).

    ``cfg`` gives the register map (unit, register, words, word order, value type, scale);
    ``mode``/``host``/``port`` in it are ignored. After :meth:`start`, :attr:`config` is a
    ModbusConfig pointing at this server.
    """

    def __init__(self, cfg: ModbusConfig, lux: float = 1000.0, *, host: str = "127.0.0.1",
                 port: int = 0, rtu: bool = False) -> None:
        self._cfg = cfg
        self.rtu = rtu
        self._modem: NullModem | None = None
        self.host = host
        self.port = port
        self._lux = float(lux)
        self.silent = False
        self.reads = 0
        self._loop: asyncio.AbstractEventLoop | None = None
        self._server: ModbusTcpServer | None = None
        self._thread: threading.Thread | None = None
        self._ready = threading.Event()
        self._error: BaseException | None = None

    @property
    def lux(self) -> float:
        """The illuminance (lux) the sensor reports."""
        return self._lux

    @lux.setter
    def lux(self, value: float) -> None:
        encode_lux(value, self._cfg)  # validate now: raises struct.error if out of range
        self._lux = float(value)

    @property
    def config(self) -> ModbusConfig:
        """The register map pointing at this server (tcp host/port, or the rtu serial port)."""
        if self.rtu:
            assert self._modem is not None, "start() the sensor first"
            return dataclasses.replace(self._cfg, mode="rtu", serial_port=self._modem.port_b)
        return dataclasses.replace(self._cfg, mode="tcp", host=self.host, port=self.port)

    async def _action(self, function_code: int, start_address: int, address: int, count: int,
                      registers: list[int], set_values: Any) -> ExcCodes | None:
        while self.silent:
            await asyncio.sleep(0.05)
        if set_values is not None:
            return ExcCodes.ILLEGAL_FUNCTION  # a lux sensor is read-only
        self.reads += 1
        regs = encode_lux(self._lux, self._cfg)
        off = self._cfg.register - start_address
        registers[off : off + len(regs)] = regs
        return None

    def _device(self) -> SimDevice:
        c = self._cfg
        size = c.register + c.words + 1

        def block() -> list[SimData]:
            return [SimData(0, count=size, values=0, datatype=DataType.REGISTERS)]

        bits = [SimData(0, count=16, values=False, datatype=DataType.BITS)]
        return SimDevice(id=c.unit, simdata=(bits, list(bits), block(), block()),
                         action=self._action)

    def _run(self) -> None:
        loop = asyncio.new_event_loop()
        self._loop = loop
        asyncio.set_event_loop(loop)

        async def main() -> None:
            if self.rtu:
                assert self._modem is not None
                self._server = ModbusSerialServer(self._device(), port=self._modem.port_a,
                                                  baudrate=self._cfg.baud)
                await self._server.serve_forever(background=True)
            else:
                self._server = ModbusTcpServer(self._device(), address=(self.host, self.port))
                await self._server.serve_forever(background=True)
                self.port = self._server.transport.sockets[0].getsockname()[1]
            self._ready.set()
            await self._server.serving

        try:
            loop.run_until_complete(main())
        except BaseException as exc:  # reported to start()
            self._error = exc
            self._ready.set()
        finally:
            pending = asyncio.all_tasks(loop)
            for t in pending:
                t.cancel()
            if pending:
                loop.run_until_complete(asyncio.gather(*pending, return_exceptions=True))
            loop.close()

    def start(self, timeout: float = 10.0) -> SimLuxSensor:
        """Start serving in a background thread; returns self once it listens."""
        if self.rtu:
            self._modem = NullModem()
        self._thread = threading.Thread(target=self._run, name="sim-lux-sensor", daemon=True)
        self._thread.start()
        if not self._ready.wait(timeout):
            raise RuntimeError("simulated lux sensor did not start")
        if self._error is not None:
            raise RuntimeError(f"simulated lux sensor failed to start: {self._error}")
        where = self._modem.port_b if self._modem else f"{self.host}:{self.port}"
        log.info("simulated lux sensor on %s unit %d", where, self._cfg.unit)
        return self

    def stop(self) -> None:
        """Stop the server and join its thread."""
        self.silent = False
        if self._loop is not None and self._server is not None and self._thread is not None:
            fut = asyncio.run_coroutine_threadsafe(self._server.shutdown(), self._loop)
            try:
                fut.result(5)
            except Exception:  # best effort at shutdown
                pass
            self._thread.join(5)
        self._thread = None
        if self._modem is not None:
            self._modem.close()
            self._modem = None

    def __enter__(self) -> SimLuxSensor:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()


def _pixel_count(ranges: tuple[tuple[int, int], ...]) -> int:
    return sum(b - a + 1 for a, b in ranges)


class SimulatedHardware:
    """Everything ``--simulate-hardware`` needs: one simulated bus per configured serial port
    (controllers at their configured addresses and pixel counts, EEPROMs persisted under
    ``root``, so tables survive a daemon restart) and, when the config names a Modbus sensor,
    a :class:`SimLuxSensor` on 127.0.0.1 reading ``lux``.

    :meth:`start` returns the config rewritten to point at the simulated devices; the port
    symlinks ``root/ports/<n>`` stay the same across restarts with the same ``root``.
    ``firmware``: what answers on the buses (:data:`~grassd.rigs.FIRMWARE_BACKENDS`: the
    Python model, or the C firmware as a process or under QEMU).
    """

    def __init__(self, cfg: Config, root: str | os.PathLike[str], lux: float = 5000.0,
                 baud: int | None = None, firmware: str = FIRMWARE_BACKENDS[0]) -> None:
        self.cfg = cfg
        self.firmware = firmware
        self.root = Path(root)
        self.lux = lux
        self.baud = baud
        self.buses: list = []
        self.sensor: SimLuxSensor | None = None
        self.ports: dict[str, str] = {}

    def start(self) -> Config:
        """Start the simulated devices; return the config that points at them."""
        by_port: dict[str, list] = {}
        for c in self.cfg.controllers:
            by_port.setdefault(c.port, []).append(c)
        (self.root / "ports").mkdir(parents=True, exist_ok=True)
        try:
            for i, (port, ctrls) in enumerate(by_port.items()):
                bus = open_bus(self.firmware, self.root / "eeprom" / f"bus{i}",
                               [c.address for c in ctrls],
                               n_pixels=[_pixel_count(c.pixels) for c in ctrls],
                               link_path=self.root / "ports" / f"bus{i}", baud=self.baud)
                self.buses.append(bus)
                bus.start()
                self.ports[port] = bus.path
            light = self.cfg.light
            if light.modbus is not None:
                self.sensor = SimLuxSensor(light.modbus, self.lux).start()
                light = dataclasses.replace(light, modbus=self.sensor.config)
        except BaseException:
            self.stop()
            raise
        controllers = tuple(dataclasses.replace(c, port=self.ports[c.port])
                            for c in self.cfg.controllers)
        return dataclasses.replace(self.cfg, controllers=controllers, light=light)

    def positions_um(self) -> np.ndarray:
        """(N,) where every display pixel's grass stands now (micrometres, row-major display
        pixels through the controllers' ``pixels`` ranges): what a camera sees. Needs the
        Python model on the buses (the C firmware keeps its motors inside its process)."""
        from grassd.daemon.core.calibration.display_model import controller_pixels

        n = self.cfg.display.rows * self.cfg.display.cols
        ports = list(dict.fromkeys(c.port for c in self.cfg.controllers))
        out = np.zeros(n)
        for c, pix in zip(self.cfg.controllers, controller_pixels(self.cfg.controllers, n),
                          strict=True):
            bus = self.buses[ports.index(c.port)]
            ctrls = getattr(bus, "controllers", None)
            if ctrls is None:
                raise RuntimeError(f"the simulated display needs --sim-firmware "
                                   f"{FIRMWARE_BACKENDS[0]}: the {self.firmware} firmware's "
                                   "motors are not visible from outside its process")
            ctrl = next(x for x in ctrls if x.config.address == c.address)
            out[pix] = ctrl.positions_um()[:len(pix)]
        return out

    def stop(self) -> None:
        """Stop every simulated device."""
        for bus in self.buses:
            bus.stop()
        self.buses.clear()
        if self.sensor is not None:
            self.sensor.stop()
            self.sensor = None


def hardware_toml(cfg: Config, baud: int | None = None) -> str:
    """The ``[display]`` size and ``[[controllers]]`` tables of ``cfg`` as TOML text, e.g. of
    the config :meth:`SimulatedHardware.start` returns, to write a configuration file that
    names the simulated ports (tests, benchmarks). Pixel ranges are inclusive indices;
    ``baud`` (line speed) is written for every controller when given.

    >>> from grassd.daemon.core.config.settings import load_default_config
    >>> print(hardware_toml(load_default_config(), baud=9600).splitlines()[:8])
    ... # doctest: +NORMALIZE_WHITESPACE
    ['[display]', 'rows = 4', 'cols = 8', '[[controllers]]',
     'port = "/dev/serial/by-id/usb-grassd_controller_0-if00"', 'address = 1', 'baud = 9600',
     'pixels = "0-15"']
    """
    speed = {} if baud is None else {"baud": baud}
    # each table's header written here, its keys by tomli-w: the text is spliced between
    # other tables of a configuration, so it must start with a header
    ctrls = "".join(
        "[[controllers]]\n" + tomli_w.dumps({
            "port": str(c.port), "address": c.address, **speed,
            "pixels": ",".join(f"{a}-{b}" for a, b in c.pixels)}) for c in cfg.controllers)
    size = {"rows": cfg.display.rows, "cols": cfg.display.cols}
    return f"[display]\n{tomli_w.dumps(size)}{ctrls}"


def start_simulated_site(cfg: Config, lux: float, firmware: str = FIRMWARE_BACKENDS[0]
                         ) -> tuple[SimulatedHardware, Config, Callable[[Config], Config]]:
    """Start simulated controllers running ``firmware`` (model, posix or qemu) + lux sensor;
    returns (hardware, new cfg, transform). Metrics then always go to the state directory
    (never to a real node_exporter's)."""
    import dataclasses

    from grassd.daemon.core.config.settings import MetricsConfig
    from grassd.daemon.core.monitoring.textfile import state_dir_textfile

    hw = SimulatedHardware(cfg, cfg.state_dir / "simhw", lux=lux, firmware=firmware)
    new = hw.start()
    camera = None
    if cfg.capture is not None:  # [capture]: a simulated OSC camera photographing the site
        from grassd.rigs.simulated_camera import start_site_camera

        camera = start_site_camera(hw)

    def transform(c: Config) -> Config:
        ctrls = tuple(dataclasses.replace(x, port=hw.ports.get(x.port, x.port))
                      for x in c.controllers)
        light = c.light
        if light.modbus is not None and hw.sensor is not None:
            light = dataclasses.replace(light, modbus=hw.sensor.config)
        cap = c.capture
        if cap is not None and camera is not None:
            cap = dataclasses.replace(cap, camera=camera.url, username="", password="")
        return dataclasses.replace(c, controllers=ctrls, light=light, capture=cap,
                                   metrics=MetricsConfig(state_dir_textfile(c.state_dir)))

    return hw, transform(new), transform
