"""The configured controllers as one fleet: push length tables to all, and reconcile.

Every controller may have a table of its own (``[tables] granularity`` "controller" or
"pixel"): :meth:`Fleet.push` takes one table for all or a mapping controller name -> table.

Controllers that share a serial port (an RS-485 bus) share one
:class:`~grassd.firmware_proto.client.ControllerClient`. Every operation takes the fleet's lock,
so the daemon's main loop and a calibration run never talk over each other. Other users of the
lines (content frames, :mod:`~grassd.daemon.content.frames`; test patterns) get the clients
from :meth:`Fleet.client` without waiting for that lock, and take turns with the fleet request
by request on each line (the client's bus lock, PROTOCOL.md section 5).

*Reconcile* (desired vs reported state, every daemon tick): read each controller's
TABLE_STATUS; one that does not report the desired table id and the CRC of its own table gets
that table pushed. A controller that was unplugged, rebooted with an old table, or missed a push
therefore receives its current table as soon as it answers again. Pushes are atomic on the
controller (staging bank, CRC-checked commit), so an interrupted push leaves the old table
active, never a mix. While content frames play on the lines (:meth:`Fleet.attach_frames`),
a push stages the table on every controller first and commits them all between two frames.

*Backoff*: a controller whose push failed is not pushed again at every reconcile. It is held
for ``retry_s`` (2 s), doubling at every further failure up to ``retry_max_s`` (5 min); its
status is still read at every pass, so it is pushed at once when it shows that it changed or
the desired table changes. Evidence of a change: it reports another table (id, CRC) than when
the failures began, or it answers again after being unreachable for longer than the current
delay (unplugged, power-cycled). A status read that fails now and then on a noisy bus is no such
evidence: the backoff keeps growing (a failed status read is no failed push: it neither
extends nor ends the backoff). A controller whose status read fails (no push tried) is
logged as not answering, one that answers it with a NAK (e.g. firmware of another protocol
version) as refusing it, one whose push failed as a failed push.
Success ends the backoff; a new :class:`Fleet` (the daemon builds one on every reload) starts
without any. :meth:`Fleet.push` (a run's own push, ``grassd calibrate --now``) ignores the
backoff and tries at once. The first failure is logged, then one line per backoff step.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from enum import Enum
from typing import Protocol

from numpy.typing import ArrayLike

from grassd.daemon.core.config.settings import ControllerConfig
from grassd.daemon.core.hardware.desired_tables import CheckedTable, DesiredTables
from grassd.daemon.core.timestamps import utc_iso
from grassd.firmware_proto.client import ControllerClient, RetryPolicy
from grassd.firmware_proto.errors import ProtocolError, PushFailed, TransientError
from grassd.firmware_proto.tables import as_table_array, table_crc

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class ControllerReport:
    """One controller's outcome: ``ok`` means it now reports table ``table_id``/``table_crc``.

    ``pushed`` is True when a transfer was made (False: it already had the table, or failed
    before transferring); ``reachable`` False when it did not answer at all. ``retry_in_s``:
    the push was held back by the controller's backoff, the next attempt is due in that many
    seconds (None: not held).
    """

    controller: str
    ok: bool
    reachable: bool
    pushed: bool
    table_id: int | None
    table_crc: int | None
    error: str | None = None
    retry_in_s: float | None = None

    def to_json(self) -> dict[str, str | bool | int | float | None]:
        """Its fields by name, in declaration order (the form runs and status carry)."""
        return {"controller": self.controller, "ok": self.ok, "reachable": self.reachable,
                "pushed": self.pushed, "table_id": self.table_id, "table_crc": self.table_crc,
                "error": self.error, "retry_in_s": self.retry_in_s}


class StatusRead(Enum):
    """How a controller answered the status read before a push attempt."""

    #: it did not answer at all
    UNREACHABLE = "unreachable"
    #: it answered with a NAK (e.g. firmware of another protocol version)
    REFUSED = "refused"
    #: it reported its table
    REPORTED = "reported"


@dataclass(frozen=True)
class ReportedState:
    """What a controller reported before a push attempt: how its status read went and, when
    it answered, whether it holds a table and that table's id and CRC. Two states compare
    equal when the controller said the same."""

    read: StatusRead
    has_table: bool = False
    table_id: int | None = None
    table_crc: int | None = None

    @property
    def answered(self) -> bool:
        """It reported its table (its status read did not fail)."""
        return self.read is StatusRead.REPORTED


#: the state of a controller whose status read got no answer
UNREACHABLE = ReportedState(StatusRead.UNREACHABLE)
#: the state of a controller that answered the status read with a NAK
REFUSED = ReportedState(StatusRead.REFUSED)


@dataclass
class PushBackoff:
    """A controller's failed pushes of one desired table: ``key`` (table id, CRC) it should
    hold, ``state`` what it reported when the failures began, the current delay and the
    monotonic time of the next attempt (seconds), failures so far, the first one's epoch time
    ``since`` and the last error. ``down_since``: monotonic time since which its status reads
    fail (None: it answers); ``changed``: it showed that it changed (module docstring), the
    next failure starts a new backoff."""

    key: tuple[int, int]
    state: ReportedState
    delay_s: float
    retry_at: float
    failures: int
    since: float
    error: str | None
    down_since: float | None = None
    changed: bool = False


class HeldDisplay(Protocol):
    """What a push needs of the frames playing on the fleet's lines: :meth:`hold` returns
    once no frame is on any line and sends none until :meth:`release`, which sends the
    newest frame again."""

    def hold(self) -> None: ...

    def release(self) -> None: ...


def table_checksum(lengths_um: ArrayLike) -> int:
    """CRC-32/ISO-HDLC of a table as the controllers compute it (uint16 little-endian bytes)."""
    return table_crc(as_table_array(lengths_um))


class Fleet:
    """All configured controllers. ``policy`` sets the protocol client's timeouts and retries;
    ``retry_s``/``retry_max_s`` the reconcile backoff of a controller whose pushes fail
    (seconds; 0 disables it). ``on_progress`` is called after every table chunk a controller
    acknowledges (the daemon's watchdog counts it as progress); once ``cancel`` is set, a push
    in progress ends at its next chunk or wait (the old table stays active)."""

    def __init__(self, controllers: Sequence[ControllerConfig],
                 policy: RetryPolicy | None = None, probe_retries: int = 1,
                 retry_s: float = 2.0, retry_max_s: float = 300.0,
                 on_progress: Callable[[], None] | None = None,
                 cancel: threading.Event | None = None) -> None:
        self.controllers = tuple(controllers)
        self.on_progress = on_progress
        self.cancel = cancel
        self.policy = policy or RetryPolicy()
        self.probe_retries = probe_retries
        self.retry_s = retry_s
        self.retry_max_s = retry_max_s
        self._clients: dict[str, ControllerClient] = {}
        self._backoff: dict[str, PushBackoff] = {}
        self._lock = threading.RLock()
        self._clients_lock = threading.Lock()  # only around the clients' dict
        self._frames: HeldDisplay | None = None

    def _client(self, c: ControllerConfig) -> ControllerClient:
        with self._clients_lock:
            client = self._clients.get(c.port)
            if client is None:
                client = ControllerClient(c.port, baudrate=c.baud, policy=self.policy,
                                          on_progress=self.on_progress, cancel=self.cancel)
                self._clients[c.port] = client
            return client

    def client(self, c: ControllerConfig) -> ControllerClient:
        """The protocol client of controller ``c``'s port (one per port, shared), for
        requests beyond pushes: test patterns (:mod:`grassd.daemon.measure.patterns`),
        content frames (:mod:`grassd.daemon.content.frames`). Does not wait for a push in
        progress: requests share the line through the client's bus lock."""
        return self._client(c)

    def attach_frames(self, frames: HeldDisplay) -> None:
        """Frames play on this fleet's lines (a
        :class:`~grassd.daemon.content.frames.FrameOutput` attaches itself): from now on
        :meth:`push` and :meth:`reconcile` stage every controller first and commit them all
        while ``frames`` is held (see :meth:`push`). Does not wait for a push in progress."""
        self._frames = frames

    def detach_frames(self, frames: HeldDisplay) -> None:
        """``frames`` stopped playing (closed): pushes are made one controller at a time
        again (from the next push on). Does nothing when another output was attached since."""
        if self._frames is frames:
            self._frames = None

    def _probe(self, c: ControllerConfig) -> int:
        """Retries of a status read: ``probe_retries`` on a clean line, the policy's
        ``retries`` on a noisy one, so that noise alone rarely makes a controller look gone."""
        noisy = self._client(c).quality.noisy()
        return max(self.probe_retries, self.policy.retries) if noisy else self.probe_retries

    def close(self) -> None:
        """Close every serial port."""
        with self._lock, self._clients_lock:
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
                                                               retries=self._probe(c)), None))
                except ProtocolError as exc:
                    out.append((c, None, str(exc)))
        return out

    def _push_one(self, c: ControllerConfig, table: CheckedTable, table_id: int,
                  hold: bool, stage: bool = False
                  ) -> tuple[ControllerReport | None, ReportedState]:
        """Push ``table`` to one controller unless it holds it (or, with ``hold``, its backoff
        holds the push back); returns the report and what it reported before the attempt.
        The status read here is the push's only one before its transfer (the client is
        given it). With ``stage`` only its first phase (:meth:`ControllerClient.stage_table`):
        the report is None once the table is staged, for :meth:`_commit_one`."""
        client = self._client(c)
        key = (table_id, table.crc)
        try:
            status = client.read_status(c.address, retries=self._probe(c))
        except TransientError as exc:
            r = ControllerReport(c.name, False, False, False, None, None, str(exc))
            return self._held(r, UNREACHABLE, key, hold), UNREACHABLE
        except ProtocolError as exc:
            r = ControllerReport(c.name, False, True, False, None, None, str(exc))
            return self._held(r, REFUSED, key, hold), REFUSED
        state = ReportedState(StatusRead.REPORTED, status.has_table, status.table_id,
                              status.table_crc)
        if status.has_table and (status.table_id, status.table_crc) == key:
            return ControllerReport(c.name, True, True, False, status.table_id,
                                    status.table_crc), state
        held = self._held(ControllerReport(c.name, False, True, False, status.table_id,
                                           status.table_crc), state, key, hold)
        if held.retry_in_s is not None:
            return held, state
        try:
            if stage:
                after = client.stage_table(c.address, table.lengths_um, table_id,
                                           status=status)
                if after is None:
                    return None, state
            else:
                after = client.push_table(c.address, table.lengths_um, table_id,
                                          status=status)
        except PushFailed as exc:
            act = exc.active
            return ControllerReport(c.name, False, act is not None, True,
                                    getattr(act, "table_id", None),
                                    getattr(act, "table_crc", None), str(exc)), state
        except TransientError as exc:
            return ControllerReport(c.name, False, False, True, None, None, str(exc)), state
        except ProtocolError as exc:  # the controller refused the table: permanent
            return ControllerReport(c.name, False, True, False, status.table_id,
                                    status.table_crc, str(exc)), state
        ok = (after.table_id, after.table_crc) == key
        return ControllerReport(c.name, ok, True, True, after.table_id, after.table_crc,
                                None if ok else "controller reports another table after "
                                                "commit"), state

    def _commit_one(self, c: ControllerConfig, table_id: int, crc: int,
                    state: ReportedState) -> ControllerReport:
        """Commit the table :meth:`_push_one` staged on ``c`` (``state``: what it reported
        before); its report, as :meth:`_push_one` makes them."""
        try:
            after = self._client(c).commit_table(c.address, table_id, crc)
        except PushFailed as exc:
            act = exc.active
            return ControllerReport(c.name, False, act is not None, True,
                                    getattr(act, "table_id", None),
                                    getattr(act, "table_crc", None), str(exc))
        except TransientError as exc:
            return ControllerReport(c.name, False, False, True, None, None, str(exc))
        except ProtocolError as exc:  # the controller refused the table: permanent
            return ControllerReport(c.name, False, True, False, state.table_id,
                                    state.table_crc, str(exc))
        return ControllerReport(c.name, True, True, True, after.table_id, after.table_crc)

    def _held(self, r: ControllerReport, state: ReportedState, key: tuple[int, int],
              hold: bool) -> ControllerReport:
        """``r`` marked as held back (``retry_in_s``) when ``hold`` and the controller's
        backoff for the same desired table has not run out and the controller did not show
        that it changed (see the module docstring); else ``r``. Notes in the backoff when the
        controller stops answering (``state`` not a report) and whether, answering again, it
        changed."""
        b = self._backoff.get(r.controller)
        now = time.monotonic()
        if b is None or b.key != key:
            return r
        if not state.answered:  # its status read failed: it says nothing about its table
            if b.down_since is None:
                b.down_since = now
        else:
            down_s = None if b.down_since is None else now - b.down_since
            if state != b.state or (down_s is not None and down_s > b.delay_s):
                b.changed = True
            b.down_since = None
        if not hold or b.changed or now >= b.retry_at:
            return r
        return replace(r, error=r.error or b.error, retry_in_s=b.retry_at - now)

    def _note(self, r: ControllerReport, state: ReportedState, key: tuple[int, int]) -> None:
        """Update the backoff of ``r``'s controller and log: success ends it (logged when it
        had failed before); a failure starts it (the same desired table and reported state)
        or doubles it, one warning each; a held push is not logged. A controller whose status
        read failed (no push tried) is logged as not answering (or, answered with a NAK, as
        refusing it), not as a failed push."""
        name = r.controller
        b = self._backoff.get(name)
        if r.ok:
            if self._backoff.pop(name, None) is not None:
                log.info("controller %s: table %d (crc %#010x) active after %d failed "
                         "push(es)", name, key[0], key[1], b.failures)
            elif r.pushed:
                log.info("controller %s: table %d (crc %#010x) active", name, *key)
            return
        if r.retry_in_s is not None:
            return
        now = time.monotonic()
        if b is None or b.key != key or b.changed:
            b = PushBackoff(key, state, self.retry_s, now + self.retry_s, 1, time.time(),
                            r.error, None if state.answered else now)
            self._backoff[name] = b
            if state.answered:
                log.warning("controller %s: push failed: %s; next attempt in %g s", name,
                            r.error, b.delay_s)
            elif state.read is StatusRead.REFUSED:  # it answers, with a NAK: another cause,
                # another fix
                log.warning("controller %s: refuses the status request: %s", name, r.error)
            else:
                log.warning("controller %s: not answering: %s", name, r.error)
            return
        if not state.answered:  # not answering within a backoff: no push was tried
            return
        b.failures += 1
        b.delay_s = min(b.delay_s * 2, self.retry_max_s)
        b.retry_at, b.error = now + b.delay_s, r.error
        since = utc_iso(b.since)
        log.warning("controller %s: push failed again (%d failures since %s): %s; next "
                    "attempt in %g s", name, b.failures, since, r.error, b.delay_s)

    def backoff(self) -> dict[str, dict[str, object]]:
        """Controller name -> its push backoff (``failures``, ``since`` epoch s, ``delay_s``,
        ``retry_in_s`` until the next attempt, ``error``) for controllers whose pushes fail.
        Safe to call from another thread (reads a snapshot)."""
        now = time.monotonic()
        return {name: {"failures": b.failures, "since": b.since, "delay_s": b.delay_s,
                       "retry_in_s": max(b.retry_at - now, 0.0), "error": b.error}
                for name, b in dict(self._backoff).items()}

    def line_quality(self) -> dict[str, dict[str, object]]:
        """Serial port -> how frames get through it (adaptive chunk size, tries without an
        answer: :meth:`~grassd.firmware_proto.line_quality.LineQuality.snapshot`), for the
        ports used so far. Safe to call from another thread (reads a snapshot)."""
        return {port: client.quality.snapshot() for port, client in dict(self._clients).items()}

    def push(self, lengths_um: ArrayLike | Mapping[str, ArrayLike], table_id: int,
             stop: threading.Event | None = None,
             fallback: ArrayLike | None = None, hold: bool = False) -> list[ControllerReport]:
        """Make the desired table with id ``table_id`` active on every controller (those that
        already hold it are left alone): :meth:`apply` of those tables.

        ``lengths_um``: one table for every controller (uint16 micrometres, (256,), or
        (n_pixels, 256) per-pixel tables), or a mapping controller name (``port#address``) ->
        that controller's own table ((256,) or (n_pixels, 256) for the pixels it drives);
        controllers missing from the mapping get ``fallback`` (a ValueError names them when
        there is none)."""
        if isinstance(lengths_um, Mapping):
            desired = DesiredTables.of(table_id, fallback, lengths_um,
                                       controllers=[c.name for c in self.controllers])
        else:
            desired = DesiredTables.of(table_id, lengths_um)
        return self.apply(desired, stop=stop, hold=hold)

    def apply(self, desired: DesiredTables, *, stop: threading.Event | None = None,
              hold: bool = False) -> list[ControllerReport]:
        """Make ``desired`` active on every controller: each one's reported id and CRC are
        checked against its own entry (:meth:`DesiredTables.for_controller`), and those that
        already hold it are left alone (one status read each). Stops between controllers
        once ``stop`` is set; the controllers not reached are simply absent from the result
        (the next reconcile serves them). Every controller is tried at once (``hold`` True:
        not one whose backoff holds its push back, see the module docstring); failures start
        or extend its backoff. While frames play (:meth:`attach_frames`) the push goes in two
        phases (:meth:`_push_in_two_phases`): no frame is shown through the old table on some
        controllers and the new on others."""
        tables = {c.name: desired.for_controller(c.name) for c in self.controllers}
        table_id = int(desired.table_id)
        out = []
        with self._lock:
            frames = self._frames
            if frames is not None:
                return self._push_in_two_phases(frames, tables, table_id, stop, hold)
            for c in self.controllers:
                if stop is not None and stop.is_set():
                    break
                table = tables[c.name]
                r, state = self._push_one(c, table, table_id, hold)
                self._note(r, state, (table_id, table.crc))
                out.append(r)
        return out

    def _push_in_two_phases(self, frames: HeldDisplay, tables: dict[str, CheckedTable],
                            table_id: int, stop: threading.Event | None,
                            hold: bool) -> list[ControllerReport]:
        """:meth:`apply` while frames play (:meth:`attach_frames`): stage the table on every
        controller that needs it, then, with the frames held (no frame on any line), commit
        them back to back and release the frames, so every frame is shown through the old
        tables on all controllers or through the new ones on all. Once ``stop`` (or the
        fleet's ``cancel``) is set while staging, nothing is committed (the staged controllers
        are absent from the result, the old tables stay active)."""
        reports: list[tuple[ControllerConfig, ControllerReport | None, ReportedState]] = []
        for c in self.controllers:
            if stop is not None and stop.is_set():
                break
            r, state = self._push_one(c, tables[c.name], table_id, hold, stage=True)
            reports.append((c, r, state))
        staged = [i for i, (_, r, _) in enumerate(reports) if r is None]
        stopped = any(e is not None and e.is_set() for e in (stop, self.cancel))
        if staged and not stopped:
            frames.hold()
            try:
                for i in staged:
                    c, _, state = reports[i]
                    reports[i] = (c, self._commit_one(c, table_id, tables[c.name].crc, state),
                                  state)
            finally:
                frames.release()
        out = []
        for c, r, state in reports:
            if r is None:  # staged, not committed: stopped
                continue
            self._note(r, state, (table_id, tables[c.name].crc))
            out.append(r)
        return out

    def reconcile(self, lengths_um: ArrayLike | Mapping[str, ArrayLike], table_id: int,
                  stop: threading.Event | None = None,
                  fallback: ArrayLike | None = None) -> list[ControllerReport]:
        """:meth:`push` with the backoff: controllers that hold their desired table cost one
        status read; one that came back (unplugged, rebooted with an old table) gets its own
        table; one whose pushes keep failing is tried again only when its backoff runs out
        or what it reports changes (its report then has ``retry_in_s``)."""
        return self.push(lengths_um, table_id, stop, fallback, hold=True)
