"""``grassd controllers``: scan, inspect, load and simulate the display's controllers.

The table file format for ``push`` is described in firmware_proto/PROTOCOL.md §6: JSON (a list
of 256 integers, a list of per-pixel lists, or ``{"lengths_um": ..., "table_id": ...}``) or CSV
(one row of 256 integers per table). Values are green-grass lengths in micrometres.

``scan``, ``status`` and ``push`` refuse to run on a serial port that a grassd daemon holding
the state directory of the configuration (``--config``, else /etc/grassd/grassd.toml, else the
embedded default) owns: a second master on an RS-485 bus garbles both sides' frames (a push
could also be undone by the daemon's next reconcile). Other ports (a spare controller on a
bench adapter) stay usable while the daemon runs (while an older grassd that does not list its
ports runs, every port is refused). Use ``grassd calibrate
--now`` to have the daemon push, ``grassd status`` to see each controller's table as the daemon
sees it, or stop the daemon. The read-only commands are refused too rather than sent through
the daemon: its control socket reports the controllers from its database, not a fresh scan.
"""

from __future__ import annotations

import signal
import tempfile
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import click

from grassd.daemon.core.runtime.statelock import StateLock
from grassd.firmware_proto.client import ControllerClient, RetryPolicy
from grassd.firmware_proto.errors import ControllerTimeout, ProtocolError, PushFailed
from grassd.firmware_proto.framing import MAX_ADDRESS, MIN_ADDRESS
from grassd.firmware_proto.messages import TableKind
from grassd.firmware_proto.table_file import load_table_file
from grassd.rigs import FIRMWARE_BACKENDS


def parse_addresses(text: str) -> list[int]:
    """``"1-4,7"`` -> [1, 2, 3, 4, 7]; addresses must be 1..247.

    >>> parse_addresses("1-3,7")
    [1, 2, 3, 7]
    """
    out: set[int] = set()
    for part in text.split(","):
        part = part.strip()
        try:
            lo, _, hi = part.partition("-")
            a, b = int(lo), int(hi or lo)
        except ValueError:
            raise click.BadParameter(f"{part!r} is not an address or range like 1-8") from None
        if not (MIN_ADDRESS <= a <= b <= MAX_ADDRESS):
            raise click.BadParameter(f"{part!r}: addresses are {MIN_ADDRESS}..{MAX_ADDRESS}")
        out.update(range(a, b + 1))
    return sorted(out)


def _addresses_option(default: str | None):
    return click.option("--addresses", "-a", default=default, show_default=default is not None,
                        help="controller addresses, e.g. 1-8,12 (default: those a scan finds)")


_port = click.option("--port", "-p", required=True,
                     help="serial port, e.g. /dev/ttyUSB0 or a pty printed by 'controllers sim'")
_baud = click.option("--baud", default=115_200, show_default=True, help="line speed (baud)")
_rs485 = click.option("--rs485", is_flag=True,
                      help="drive the RS-485 transceiver from RTS via the kernel's RS-485 mode "
                           "(native UARTs only; USB adapters switch direction themselves)")
_timeout = click.option("--timeout", "timeout_s", default=0.25, show_default=True,
                        help="answer timeout per request (seconds), before retries")


_config = click.option("--config", "config_path", type=click.Path(dir_okay=False),
                       help="configuration whose daemon must not be running (default "
                            "/etc/grassd/grassd.toml, else the embedded default)")
_state_dir = click.option("--state-dir", type=click.Path(file_okay=False),
                          help="override the configuration's state directory")

#: what to use instead of a read-only command on a bus the daemon owns
_SEE_STATUS = "`grassd status` (each controller's table as the daemon sees it)"


@contextmanager
def _bus_free(config_path: str | None, state_dir: str | None, command: str,
              instead: str, port: str) -> Iterator[None]:
    """Run the block only while no grassd daemon holds the configuration's state directory
    (:meth:`StateLock.shared`, kept until the block ends so that a daemon starting meanwhile
    waits) or the daemon holding it does not own ``port``; else StateDirLocked, one line
    saying to use ``instead`` or stop the daemon."""
    from grassd.daemon.core.runtime.state_owner import config_as_state_owner

    cfg = config_as_state_owner(config_path, state_dir, f"controllers {command}")

    def refuse(holder: str) -> str:
        return (f"state directory {cfg.state_dir} is in use by {holder}, which owns the "
                f"controllers' serial buses: `grassd controllers {command}` would talk over "
                f"it; use {instead}, or stop the daemon first")

    with StateLock(cfg.state_dir).shared(refuse, port=port):
        yield


@contextmanager
def _client(port: str, baud: int, timeout_s: float,
            rs485: bool = False) -> Iterator[ControllerClient]:
    with ControllerClient(port, baudrate=baud, policy=RetryPolicy(timeout_s=timeout_s),
                          rs485=rs485) as c:
        yield c


def _targets(client: ControllerClient, addresses: str | None) -> list[int]:
    if addresses is not None:
        return parse_addresses(addresses)
    found = sorted(client.scan(range(1, 33)))
    if not found:
        raise ControllerTimeout(f"no controller answered on {client.port} (addresses 1-32); "
                                f"check the port, wiring and baud rate, or give --addresses")
    return found


@click.group("controllers")
def controllers() -> None:
    """Talk to the display's controllers over serial, or run simulated ones."""


@controllers.command("scan")
@_port
@_addresses_option("1-32")
@_baud
@click.option("--timeout", "timeout_s", default=0.05, show_default=True,
              help="answer timeout per address (seconds)")
@_rs485
@_config
@_state_dir
def scan_cmd(port: str, addresses: str, baud: int, timeout_s: float, rs485: bool,
             config_path: str | None, state_dir: str | None) -> None:
    """Send HELLO to each address and list the controllers that answer.

    \b
    Refused while a running daemon holds the configuration's state directory (it owns the
    serial buses): see `grassd status`, or stop the daemon.
    """
    with _bus_free(config_path, state_dir, "scan", _SEE_STATUS, port), \
            _client(port, baud, timeout_s, rs485) as client:
        found = client.scan(parse_addresses(addresses), timeout_s=timeout_s)
    if not found:
        raise ControllerTimeout(f"no controller answered on {port} (addresses {addresses}); "
                                f"check the port, wiring and baud rate")
    for a, info in found.items():
        click.echo(f"address {a}: uid {info.uid:#010x}, firmware {info.firmware_version}, "
                   f"protocol {info.protocol_version}, {info.n_pixels} pixels, "
                   f"{info.table_capacity} tables/bank, max chunk {info.max_chunk} B, "
                   f"max length {info.max_length_um} um")


@controllers.command("status")
@_port
@_addresses_option(None)
@_baud
@_timeout
@_rs485
@_config
@_state_dir
def status_cmd(port: str, addresses: str | None, baud: int, timeout_s: float,
               rs485: bool, config_path: str | None, state_dir: str | None) -> None:
    """Print the active table (id, CRC-32, generation, bank) of each controller.

    \b
    Refused while a running daemon holds the configuration's state directory (it owns the
    serial buses): see `grassd status`, or stop the daemon.
    """
    with _bus_free(config_path, state_dir, "status", _SEE_STATUS, port), \
            _client(port, baud, timeout_s, rs485) as client:
        for a in _targets(client, addresses):
            st = client.read_status(a)
            if not st.has_table:
                line = "no table"
            else:
                kind = "global" if st.kind == TableKind.GLOBAL else f"{st.n_tables} per-pixel"
                line = (f"table {st.table_id:#010x} crc {st.table_crc:#010x} "
                        f"generation {st.generation} bank {st.active_bank} ({kind})")
            if st.staging:
                line += f", transfer open ({st.staged_bytes} bytes staged)"
            click.echo(f"address {a}: {line}")


@controllers.command("push")
@_port
@click.option("--table", "table_file", required=True, type=click.Path(dir_okay=False),
              help="table file: JSON list of 256 um values (or per-pixel lists, or "
                   '{"lengths_um": ..., "table_id": N}), or CSV with 256 values per row')
@click.option("--table-id", type=click.IntRange(0, 0xFFFFFFFF), default=None,
              help="id to store with the table (default: the file's, else the table's CRC-32)")
@_addresses_option(None)
@_baud
@_timeout
@_rs485
@_config
@_state_dir
def push_cmd(port: str, table_file: str, table_id: int | None, addresses: str | None,
             baud: int, timeout_s: float, rs485: bool, config_path: str | None,
             state_dir: str | None) -> None:
    """Load a length table into controllers: staged, CRC-checked, switched atomically.

    \b
    Refused while a running daemon holds the configuration's state directory (it owns the
    serial buses): use `grassd calibrate --now`, or stop the daemon.
    """
    table, file_id = load_table_file(table_file)
    tid = table_id if table_id is not None else file_id
    failures: list[str] = []
    with _bus_free(config_path, state_dir, "push", "`grassd calibrate --now` (the daemon "
                   "calibrates and pushes its table)", port), \
            _client(port, baud, timeout_s, rs485) as client:
        targets = _targets(client, addresses)
        for a in targets:
            try:
                st = client.push_table(a, table, tid)
            except ProtocolError as exc:
                click.echo(f"address {a}: FAILED: {exc}", err=True)
                failures.append(str(a))
                continue
            click.echo(f"address {a}: table {st.table_id:#010x} crc {st.table_crc:#010x} "
                       f"active (generation {st.generation})")
    if failures:
        raise PushFailed(f"push failed on {len(failures)} of {len(targets)} controllers "
                         f"(addresses {', '.join(failures)}); their previous tables stay active",
                         active=None)


@controllers.command("sim")
@click.option("--pty/--no-pty", "use_pty", default=True,
              help="attach the simulated controllers to pseudo-terminals (the only transport)")
@click.option("--count", "-n", default=4, show_default=True, type=click.IntRange(1, 247),
              help="number of simulated controllers")
@click.option("--separate", is_flag=True,
              help="one pty per controller (USB style, each address 1) instead of one shared "
                   "RS-485-style bus with addresses 1..count")
@click.option("--pixels", default=16, show_default=True, type=click.IntRange(1, 4096),
              help="grass pixels per controller")
@click.option("--state-dir", type=click.Path(file_okay=False),
              help="where the controllers' EEPROM files live (default: a new temp directory)")
@click.option("--link-dir", type=click.Path(file_okay=False),
              help="where to put stable symlinks bus0, bus1... to the ptys (default: state dir)")
@click.option("--baud", type=int, default=None,
              help="pace the simulated line at this baud rate (default: unpaced)")
@click.option("--duration", type=float, default=None,
              help="stop after this many seconds (default: run until Ctrl-C)")
@click.option("--firmware", type=click.Choice(FIRMWARE_BACKENDS), default=FIRMWARE_BACKENDS[0],
              show_default=True,
              help="what answers: the Python model, the C firmware as a Linux process (posix), "
                   "or its Cortex-M7 image under qemu-system-arm (qemu)")
def sim_cmd(use_pty: bool, count: int, separate: bool, pixels: int, state_dir: str | None,
            link_dir: str | None, baud: int | None, duration: float | None,
            firmware: str) -> None:
    """Start simulated controllers on ptys, print their ports, run until Ctrl-C."""
    if not use_pty:
        raise click.UsageError("only --pty is implemented: simulated controllers live on ptys")
    from grassd.rigs.sim_backends import start_buses  # simulated hardware: this command only

    state = Path(state_dir) if state_dir else Path(tempfile.mkdtemp(prefix="grassd-sim-"))
    links = Path(link_dir) if link_dir else state
    buses = start_buses(firmware, state, count, shared=not separate, link_dir=links, baud=baud,
                        n_pixels=pixels)
    stop = {"now": False}

    def _on_signal(signum, _frame):
        stop["now"] = True

    # Ctrl-C and SIGTERM stop it the same way, wherever they arrive (a KeyboardInterrupt
    # between printing the ports and the loop below would abort with status 1)
    old = {s: signal.signal(s, _on_signal) for s in (signal.SIGTERM, signal.SIGINT)}
    try:
        for bus in buses:
            addrs = [c.config.address for c in bus.controllers]
            span = f"{addrs[0]}-{addrs[-1]}" if len(addrs) > 1 else str(addrs[0])
            click.echo(f"{bus.path} -> {bus.device}  addresses {span}, {pixels} pixels each")
        click.echo(f"EEPROM files in {state}; Ctrl-C to stop", err=True)
        deadline = None if duration is None else time.monotonic() + duration
        while not stop["now"] and (deadline is None or time.monotonic() < deadline):
            time.sleep(0.1)
    finally:
        for s, handler in old.items():
            signal.signal(s, handler)
        for bus in buses:
            bus.stop()
    click.echo("simulated controllers stopped", err=True)
