"""The configured controllers as one fleet: push length tables to all, and reconcile.

Every controller may have a table of its own (``[tables] granularity`` "controller" or
"pixel"): :meth:`Fleet.push` takes one table for all or a mapping controller name -> table.

Controllers that share a serial port (an RS-485 bus) share one
:class:`~grassd.firmware_proto.client.ControllerClient`. Every operation takes the fleet's lock,
so the daemon's main loop and a calibration run never talk over each other.

*Reconcile* (desired vs reported state, every daemon tick): read each controller's
TABLE_STATUS; one that does not report the desired table id and the CRC of its own table gets
that table pushed. A controller that was unplugged, rebooted with an old table, or missed a push
therefore receives its current table as soon as it answers again. Pushes are atomic on the
controller (staging bank, CRC-checked commit), so an interrupted push leaves the old table
active, never a mix.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import ArrayLike

from grassd.daemon.config import ControllerConfig
from grassd.firmware_proto.client import ControllerClient, RetryPolicy
from grassd.firmware_proto.errors import ProtocolError, PushFailed, TransientError
from grassd.firmware_proto.tables import as_table_array, table_crc

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class ControllerReport:
    """One controller's outcome: ``ok`` means it now reports table ``table_id``/``table_crc``.

    ``pushed`` is True when a transfer was made (False: it already had the table, or failed
    before transferring); ``reachable`` False when it did not answer at all.
    """

    controller: str
    ok: bool
    reachable: bool
    pushed: bool
    table_id: int | None
    table_crc: int | None
    error: str | None = None


def table_checksum(lengths_um: ArrayLike) -> int:
    """CRC-32/ISO-HDLC of a table as the controllers compute it (uint16 little-endian bytes)."""
    return table_crc(as_table_array(lengths_um))


class Fleet:
    """All configured controllers. ``policy`` sets the protocol client's timeouts and retries."""

    def __init__(self, controllers: Sequence[ControllerConfig],
                 policy: RetryPolicy | None = None, probe_retries: int = 1) -> None:
        self.controllers = tuple(controllers)
        self.policy = policy or RetryPolicy()
        self.probe_retries = probe_retries
        self._clients: dict[str, ControllerClient] = {}
        self._lock = threading.RLock()

    def _client(self, c: ControllerConfig) -> ControllerClient:
        client = self._clients.get(c.port)
        if client is None:
            client = ControllerClient(c.port, baudrate=c.baud, policy=self.policy)
            self._clients[c.port] = client
        return client

    def close(self) -> None:
        """Close every serial port."""
        with self._lock:
            for client in self._clients.values():
                client.close()
            self._clients.clear()

    def __enter__(self) -> Fleet:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def read_all(self) -> list[tuple[ControllerConfig, object | None, str | None]]:
        """(controller, TableStatus or None, error or None) for every controller."""
        out = []
        with self._lock:
            for c in self.controllers:
                try:
                    out.append((c, self._client(c).read_status(c.address,
                                                               retries=self.probe_retries), None))
                except ProtocolError as exc:
                    out.append((c, None, str(exc)))
        return out

    def _push_one(self, c: ControllerConfig, table: np.ndarray, table_id: int, crc: int,
                  force_probe: bool) -> ControllerReport:
        client = self._client(c)
        try:
            status = client.read_status(c.address, retries=self.probe_retries)
        except TransientError as exc:
            return ControllerReport(c.name, False, False, False, None, None, str(exc))
        except ProtocolError as exc:
            return ControllerReport(c.name, False, True, False, None, None, str(exc))
        if status.has_table and (status.table_id, status.table_crc) == (table_id, crc):
            return ControllerReport(c.name, True, True, False, status.table_id, status.table_crc)
        try:
            after = client.push_table(c.address, table, table_id)
        except PushFailed as exc:
            act = exc.active
            return ControllerReport(c.name, False, act is not None, True,
                                    getattr(act, "table_id", None),
                                    getattr(act, "table_crc", None), str(exc))
        except TransientError as exc:
            return ControllerReport(c.name, False, False, True, None, None, str(exc))
        except ProtocolError as exc:  # the controller refused the table: permanent
            return ControllerReport(c.name, False, True, False, status.table_id,
                                    status.table_crc, str(exc))
        ok = (after.table_id, after.table_crc) == (table_id, crc)
        return ControllerReport(c.name, ok, True, True, after.table_id, after.table_crc,
                                None if ok else "controller reports another table after commit")

    def push(self, lengths_um: ArrayLike | Mapping[str, ArrayLike], table_id: int,
             stop: threading.Event | None = None,
             fallback: ArrayLike | None = None) -> list[ControllerReport]:
        """Make the desired table with id ``table_id`` active on every controller (those that
        already hold it are left alone).

        ``lengths_um``: one table for every controller (uint16 micrometres, (256,), or
        (n_pixels, 256) per-pixel tables), or a mapping controller name (``port#address``) ->
        that controller's own table ((256,) or (n_pixels, 256) for the pixels it drives);
        controllers missing from the mapping get ``fallback`` (a ValueError names them when
        there is none). Each controller's reported id and CRC are checked against its own
        table. Stops between controllers once ``stop`` is set; the controllers not reached
        are simply absent from the result (the next reconcile serves them)."""
        desired = self._desired(lengths_um, fallback)
        out = []
        with self._lock:
            for c in self.controllers:
                if stop is not None and stop.is_set():
                    break
                table, crc = desired[c.name]
                r = self._push_one(c, table, int(table_id), crc, True)
                (log.info if r.ok else log.warning)(
                    "controller %s: %s", c.name,
                    f"table {table_id} (crc {crc:#010x}) active" if r.ok
                    else f"push failed: {r.error}")
                out.append(r)
        return out

    def reconcile(self, lengths_um: ArrayLike | Mapping[str, ArrayLike], table_id: int,
                  stop: threading.Event | None = None,
                  fallback: ArrayLike | None = None) -> list[ControllerReport]:
        """Same as :meth:`push`: controllers that hold their desired table cost one status
        read; one that came back (unplugged, rebooted with an old table) gets its own table."""
        return self.push(lengths_um, table_id, stop, fallback)

    def _desired(self, lengths_um: ArrayLike | Mapping[str, ArrayLike],
                 fallback: ArrayLike | None) -> dict[str, tuple[np.ndarray, int]]:
        """(validated table, CRC) for every controller's name."""
        if not isinstance(lengths_um, Mapping):
            table = as_table_array(lengths_um)
            crc = table_crc(table)
            return {c.name: (table, crc) for c in self.controllers}
        missing = [c.name for c in self.controllers if c.name not in lengths_um]
        if missing and fallback is None:
            raise ValueError(f"no table for controller(s) {', '.join(missing)} and no fallback")
        out = {}
        for c in self.controllers:
            table = as_table_array(lengths_um[c.name] if c.name in lengths_um else fallback)
            out[c.name] = (table, table_crc(table))
        return out


def with_ports(controllers: Sequence[ControllerConfig],
               ports: dict[str, str]) -> tuple[ControllerConfig, ...]:
    """Controllers with their ``port`` replaced through the mapping ``ports`` (old -> new)."""
    return tuple(replace(c, port=ports.get(c.port, c.port)) for c in controllers)
