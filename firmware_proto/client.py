"""Host side of the protocol: talk to controllers over a serial port (PROTOCOL.md §5).

:class:`ControllerClient` sends requests, waits for the matching answer (address, seq, type),
retransmits on timeout with exponential backoff and jitter, reopens a port that vanished, and
turns every failure into a specific :mod:`~.errors` exception. :func:`push_table`,
:func:`read_status`, :func:`hello` and :func:`scan` are one-call helpers for the daemon.

Typical use (the daemon reconciling one controller)::

    with ControllerClient("/dev/ttyUSB0") as client:
        status = client.read_status(address=1)
        if status.table_id != desired_id:
            status = client.push_table(1, lengths_um, table_id=desired_id)
"""

from __future__ import annotations

import math
import random
import threading
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import ArrayLike

from grassd.firmware_proto.bus_lock import BusLock
from grassd.firmware_proto.codec import Frame, encode_frame
from grassd.firmware_proto.errors import (
    AddressError,
    ControllerTimeout,
    NakError,
    PortUnavailable,
    ProtocolError,
    PushFailed,
    TableError,
    TransferInterrupted,
    TransientError,
)
from grassd.firmware_proto.framing import BROADCAST_ADDRESS, MAX_ADDRESS, MIN_ADDRESS
from grassd.firmware_proto.line_quality import LineQuality
from grassd.firmware_proto.link import SerialLink
from grassd.firmware_proto.messages import (
    MAX_CHUNK_DATA,
    MAX_PATTERN_PIXELS,
    MAX_POSITIONS,
    MAX_STAGE_PIXELS,
    RESPONSE_TYPES,
    Ack,
    GetPositions,
    GetStatus,
    Hello,
    Info,
    Message,
    MsgType,
    Nak,
    NakCode,
    Pattern,
    PatternEnd,
    Positions,
    SetLevel,
    Show,
    StageLevel,
    TableBegin,
    TableChunk,
    TableCommit,
    TableKind,
    TableStatus,
    nak_name,
)
from grassd.firmware_proto.tables import (
    as_table_array,
    table_bytes,
    table_crc,
    table_kind,
)

#: NAKs after which restarting the transfer from TABLE_BEGIN can succeed.
RESTARTABLE_NAKS = frozenset({NakCode.NO_TRANSFER, NakCode.INCOMPLETE, NakCode.CRC_MISMATCH,
                              NakCode.STORAGE_FAILED})

#: Default wall-clock limit of one :meth:`ControllerClient.push_table`, in seconds: HELLO,
#: status, every transfer and restart, and the read-back together. A controller that answered
#: each chunk just before the request timeout and refused every commit held one push for
#: ~9 min; now it holds the caller at most this long, then the push fails with
#: :class:`PushFailed` (transient: the daemon keeps the old table and retries with backoff).
#: The wall-clock deadline of one push (s) is this, or the table's bytes over
#: :data:`MIN_PUSH_BYTES_PER_S`, whichever is longer. 25 s holds a 512-byte table on a line with
#: 1 % byte errors at 115200 baud (12.1 s at most: ``bench_noisy_line``,
#: docs/operating/service.md) with room.
#: A stalling controller (each chunk answered just before its timeout, every commit refused)
#: held one push for 348 s before there was a deadline.
PUSH_DEADLINE_S = 25.0
#: The slowest average a push may make (bytes of table per second) before its deadline cuts it:
#: 16 per-pixel tables (8 KiB) on that 1 %-error line took 83-173 s (48-99 B/s), so their
#: deadline is 205 s. The daemon's watchdog is fed while chunks are acknowledged
#: (:attr:`ControllerClient.on_progress`), not only between pushes, and a stop request ends
#: the push at the next chunk (:attr:`ControllerClient.cancel`): the old table stays active.
MIN_PUSH_BYTES_PER_S = 40.0

#: Largest payload of each answer type (bytes), to size timeouts at low baud rates.
_MAX_ANSWER_PAYLOAD = {MsgType.INFO: 18, MsgType.TABLE_STATUS: 21, MsgType.ACK: 1,
                       MsgType.POSITIONS: 2 + 4 * MAX_POSITIONS}


@dataclass(frozen=True)
class RetryPolicy:
    """Timeouts and retry counts of a :class:`ControllerClient` (seconds).

    ``timeout_s`` is the turn-around margin per request; the time the request and the longest
    answer take on the wire at the client's baud rate is added to it.
    """

    timeout_s: float = 0.25
    retries: int = 4  #: retransmissions of one request after the first try
    backoff_s: float = 0.02  #: first backoff; doubles each retry, with jitter x0.5..1.5
    backoff_max_s: float = 0.5
    restarts: int = 3  #: restarts of a table transfer from TABLE_BEGIN
    readback_retries: int = 10  #: retries when reading TABLE_STATUS back after a push
    chunk_bytes: int = MAX_CHUNK_DATA  #: largest chunk this host sends (device limit applies)
    #: adapt the chunk size to the line (see :mod:`~.line_quality`): halve it after a failed
    #: chunk down to min_chunk_bytes, double it after chunk_grow_after clean chunks in a row
    adaptive_chunks: bool = True
    min_chunk_bytes: int = 16
    chunk_grow_after: int = 2
    #: tries in a row of a chunk that cannot shrink any further before the transfer restarts
    #: (more than ``retries``: at 1 % byte errors a 16-byte chunk gets through 60 % of tries)
    chunk_floor_tries: int = 8
    #: wall-clock limit of one push_table call, in seconds, or the table's size over
    #: ``min_push_bytes_per_s`` where that is longer (see :data:`PUSH_DEADLINE_S`)
    push_deadline_s: float = PUSH_DEADLINE_S
    min_push_bytes_per_s: float = MIN_PUSH_BYTES_PER_S

    def push_deadline_for(self, n_bytes: int) -> float:
        """The wall-clock deadline (s) of a push of ``n_bytes`` bytes of table data."""
        return max(self.push_deadline_s, n_bytes / self.min_push_bytes_per_s)

    def __post_init__(self) -> None:
        if not self.push_deadline_s > 0:
            raise ValueError(f"push_deadline_s must be > 0 s, got {self.push_deadline_s!r}")
        if not self.min_push_bytes_per_s > 0:
            raise ValueError(f"min_push_bytes_per_s must be > 0, got "
                             f"{self.min_push_bytes_per_s!r}")
        if not 1 <= self.min_chunk_bytes <= MAX_CHUNK_DATA:
            raise ValueError(f"min_chunk_bytes must be 1..{MAX_CHUNK_DATA}, got "
                             f"{self.min_chunk_bytes!r}")


#: Longest watchdog a test pattern may have (s): PATTERN's timeout_ds is a u16 of 0.1 s.
MAX_PATTERN_TIMEOUT_S = 0xFFFF / 10


class ControllerUnsupported(ProtocolError):
    """A controller advertises limits this host will not work with, or lacks a feature asked
    for (a permanent refusal, before anything is sent): e.g. a ``max_chunk`` below
    :attr:`RetryPolicy.min_chunk_bytes`, which would let it stretch one push over thousands of
    requests, or test patterns on a controller whose INFO lacks the feature bit. The message
    says what to change on the controller."""


class _PushDeadline(TransientError):
    """The push's wall-clock deadline passed (internal: :meth:`ControllerClient.push_table`
    turns it into :class:`PushFailed`)."""


class _PushStopped(_PushDeadline):
    """The push was stopped by the client's ``cancel`` event before its deadline (internal,
    turned into :class:`PushFailed` as :class:`_PushDeadline` is)."""


def _table_matches(status: TableStatus, table_id: int, crc: int) -> bool:
    return status.has_table and (status.table_id, status.table_crc) == (table_id, crc)


class ControllerClient:
    """Requests to controllers on one serial port (one controller, or an RS-485 bus of them).

    ``port`` is a device path; ``baudrate`` the line speed (also used to size timeouts);
    ``seed`` fixes the starting sequence number and backoff jitter (for reproducible tests);
    ``rs485`` turns on the kernel's RS-485 direction control (see :class:`~.link.SerialLink`).
    ``link``: another transport with SerialLink's ``send`` / ``receive`` / ``close`` (e.g. the
    in-process :class:`~.loopback.LoopbackLink` of benchmarks); ``port`` then only names it.
    :attr:`quality` tracks the line (adaptive chunk size, tries without answer).
    :attr:`on_progress` (if set) is called after every acknowledged table chunk, so that a
    long push counts as progress (the daemon's watchdog); :attr:`cancel` (if set) ends a push
    at its next wait once set, as if its deadline had passed (the old table stays active).
    Threads may share a client: every try of a request (send, then wait for the answer) holds
    :attr:`bus` (a :class:`~.bus_lock.BusLock`, first come first served), a broadcast
    :meth:`show` too, and a push releases the line between its requests, so frames, pushes and
    status reads take turns (PROTOCOL.md section 5). :attr:`chunk_cap` (bytes, None: none)
    limits the TABLE_CHUNKs of pushes from their next chunk on, while content plays.
    """

    def __init__(self, port: str, *, baudrate: int = 115_200,
                 policy: RetryPolicy | None = None, seed: int | None = None,
                 rs485: bool = False, link: SerialLink | None = None,
                 on_progress: Callable[[], None] | None = None,
                 cancel: threading.Event | None = None) -> None:
        self.link = link if link is not None else SerialLink(port, baudrate, rs485=rs485)
        self.on_progress = on_progress
        self.cancel = cancel
        self.policy = policy or RetryPolicy()
        p = self.policy
        self.quality = LineQuality(p.chunk_bytes, min(p.min_chunk_bytes, p.chunk_bytes),
                                   p.chunk_grow_after, p.adaptive_chunks)
        self._rng = random.Random(seed)
        self._seq = self._rng.randrange(0x10000)
        self.bus = BusLock()
        self.chunk_cap: int | None = None
        self.retransmissions = 0
        self.stale_frames = 0
        self._info: dict[int, Info] = {}
        #: time.monotonic() by which the push in progress must end (None: no push)
        self._deadline: float | None = None
        #: the push's last read-back, which a stop request does not cut short
        self._reading_back = False

    # --- plumbing -------------------------------------------------------------------------
    def __enter__(self) -> ControllerClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """Close the serial port."""
        self.link.close()

    @property
    def port(self) -> str:
        """The serial port's path."""
        return self.link.port

    def _wire_time(self, n_bytes: int) -> float:
        return n_bytes * 10 / self.link.baudrate  # 8N1: 10 bit times per byte

    def _backoff(self, attempt: int) -> float:
        p = self.policy
        return min(p.backoff_max_s, p.backoff_s * 2 ** (attempt - 1)) * (0.5 + self._rng.random())

    def _sleep(self, seconds: float) -> None:
        """Sleep ``seconds``, but not past the push deadline (which then raises)."""
        if self._deadline is not None:
            seconds = min(seconds, self._deadline - time.monotonic())
        if seconds > 0:
            time.sleep(seconds)
        self._check_deadline()

    def _check_deadline(self) -> None:
        if self._deadline is None:
            return
        if time.monotonic() >= self._deadline:
            raise _PushDeadline("the push deadline passed")
        if self.cancel is not None and self.cancel.is_set() and not self._reading_back:
            raise _PushStopped("the push was stopped (the daemon is stopping)")

    def request(self, address: int, message: Message, *, retries: int | None = None,
                timeout_s: float | None = None) -> Message:
        """Send ``message`` to ``address`` and return its answer (a NAK is returned, not raised).

        Retransmits the same bytes on timeout up to ``retries`` times (policy default).
        Raises :class:`ControllerTimeout` or :class:`PortUnavailable` (both transient) when
        every try failed.
        """
        if not MIN_ADDRESS <= address <= MAX_ADDRESS:
            raise AddressError(f"controller address must be {MIN_ADDRESS}..{MAX_ADDRESS}, "
                             f"got {address}")
        p = self.policy
        retries = p.retries if retries is None else retries
        seq = self._next_seq()
        wire = encode_frame(Frame(address, seq, message))
        expected = RESPONSE_TYPES[message.TYPE]
        answer = 12 + max(_MAX_ANSWER_PAYLOAD[expected], 6)  # header, CRC, COBS, delimiter
        timeout = (p.timeout_s if timeout_s is None else timeout_s) + self._wire_time(
            len(wire) + answer)
        last: TransientError | None = None
        for attempt in range(retries + 1):
            if attempt:
                self.retransmissions += 1
                self._sleep(self._backoff(attempt))
            self._check_deadline()
            try:
                with self.bus:
                    self.link.send(wire)
                    deadline = time.monotonic() + timeout
                    if self._deadline is not None:
                        deadline = min(deadline, self._deadline)
                    while (frame := self.link.receive(deadline)) is not None:
                        m = frame.message
                        if (frame.address == address and frame.seq == seq
                                and m.TYPE in (expected, MsgType.NAK)):
                            self.quality.note_try(True)
                            return m
                        self.stale_frames += 1
                self._check_deadline()  # cut short by the push's deadline: not the line's fault
                last = ControllerTimeout(f"no answer within {timeout:.3f} s")
            except PortUnavailable as exc:
                last = exc
                self._info.clear()  # whatever comes back on this port may be another board
            self.quality.note_try(False)
        what = f"controller {address} on {self.port}: {message.TYPE.name} failed after " \
               f"{retries + 1} tries"
        if isinstance(last, PortUnavailable):
            raise PortUnavailable(f"{what}: {last}")
        raise ControllerTimeout(f"{what}: {last}; check the address, wiring and baud rate")

    def _next_seq(self) -> int:
        with self.bus:
            self._seq = (self._seq + 1) & 0xFFFF
            return self._seq

    def _expect(self, address: int, message: Message, cls: type[Message], **kw) -> Message:
        reply = self.request(address, message, **kw)
        if isinstance(reply, Nak):
            text = (f"controller {address} on {self.port} refused {message.TYPE.name}: "
                    f"{nak_name(reply.error)} (detail {reply.detail})")
            if reply.error in RESTARTABLE_NAKS:
                raise TransferInterrupted(text)
            self._info.pop(address, None)  # re-read capacities before the next attempt
            raise NakError(text, code=reply.error, detail=reply.detail)
        if not isinstance(reply, cls):  # pragma: no cover - request() matches types
            raise ControllerTimeout(f"unexpected answer {reply!r}")
        return reply

    # --- queries --------------------------------------------------------------------------
    def hello(self, address: int, **kw) -> Info:
        """HELLO: the controller's versions, pixel count and capacities."""
        info = self._expect(address, Hello(), Info, **kw)
        self._info[address] = info
        return info

    def read_status(self, address: int, **kw) -> TableStatus:
        """GET_STATUS: which table (id, CRC-32, generation) is active, and any open transfer."""
        return self._expect(address, GetStatus(), TableStatus, **kw)

    def scan(self, addresses: Iterable[int] = range(MIN_ADDRESS, MAX_ADDRESS + 1), *,
             timeout_s: float = 0.05, retries: int = 1) -> dict[int, Info]:
        """HELLO each address with a short timeout; return the controllers that answered."""
        found: dict[int, Info] = {}
        for address in addresses:
            try:
                found[address] = self.hello(address, timeout_s=timeout_s, retries=retries)
            except ControllerTimeout:
                continue
        return found

    def set_levels(self, address: int, levels: ArrayLike, first_pixel: int = 0,
                   **kw) -> None:
        """SET_LEVEL: show 8-bit ``levels[i]`` on pixel ``first_pixel + i`` (``kw``: retries,
        timeout_s of :meth:`request`)."""
        lv = _levels(levels)
        self._expect(address, SetLevel(first_pixel, lv.tobytes()), Ack, **kw)

    # --- the frame latch ------------------------------------------------------------------
    def stage_levels(self, address: int, frame: int, levels: ArrayLike, first_pixel: int = 0,
                     **kw) -> None:
        """STAGE_LEVEL: stage 8-bit ``levels[i]`` for pixel ``first_pixel + i`` as part of
        frame ``frame`` (0..65535); the controller shows them at the :meth:`show` of that
        frame. More levels than one frame holds (1020) go in several STAGE_LEVELs. ``kw``:
        retries, timeout_s of :meth:`request`.

        Raises :class:`ControllerUnsupported` when the controller's INFO lacks the latch
        feature (nothing sent; send :meth:`set_levels` instead), :class:`TableError` for
        levels that are not a non-empty 1-D sequence of integers 0..255, :class:`NakError`
        when it refuses (NO_TABLE, BAD_PIXEL), and the transient errors of :meth:`request`.
        """
        lv = _levels(levels)
        self._latch_info(address)
        for start in range(0, lv.size, MAX_STAGE_PIXELS):
            part = lv[start:start + MAX_STAGE_PIXELS]
            self._expect(address, StageLevel(frame & 0xFFFF, first_pixel + start,
                                             part.tobytes()), Ack, **kw)

    def show(self, frame: int, *, line_held: bool = False) -> None:
        """SHOW, broadcast: every controller on this line that staged frame ``frame`` shows
        it now; none answers (a controller without the latch ignores it). Holds :attr:`bus`
        while it writes, unless ``line_held``: a thread of the caller's holds it and waits
        idle for this write (the frame output's line threads, so that no request gets in
        between a frame's STAGE_LEVELs and its SHOW). Raises :class:`PortUnavailable` when
        the port is gone."""
        if line_held:
            self._seq = (self._seq + 1) & 0xFFFF
            self.link.send(encode_frame(Frame(BROADCAST_ADDRESS, self._seq,
                                              Show(frame & 0xFFFF))))
            return
        with self.bus:
            self.show(frame, line_held=True)

    def supports_latch(self, address: int) -> bool:
        """Whether controller ``address`` takes STAGE_LEVEL / SHOW (its INFO, read once)."""
        info = self._info.get(address) or self.hello(address)
        return info.supports_latch

    def _latch_info(self, address: int) -> Info:
        info = self._info.get(address) or self.hello(address)
        if not info.supports_latch:
            raise ControllerUnsupported(
                f"controller {address} on {self.port} (firmware {info.firmware_version}) has "
                f"no frame latch: its INFO lacks features bit 1 (STAGE_LEVEL / SHOW). Send "
                f"SET_LEVEL to it, or flash firmware that has the latch")
        return info

    def read_positions(self, address: int, first_pixel: int = 0,
                       count: int | None = None) -> np.ndarray:
        """GET_POSITIONS: array (count, 2) of (encoder position, target) in micrometres."""
        if count is None:
            info = self._info.get(address) or self.hello(address)
            count = info.n_pixels - first_pixel
        out = []
        for start in range(first_pixel, first_pixel + count, MAX_POSITIONS):
            n = min(MAX_POSITIONS, first_pixel + count - start)
            reply = self._expect(address, GetPositions(start, n), Positions)
            out.append(np.frombuffer(reply.positions, dtype="<u2").reshape(-1, 2))
        return np.concatenate(out).astype(np.uint16)

    # --- test patterns --------------------------------------------------------------------
    def show_pattern(self, address: int, lengths_um: Sequence[int] | ArrayLike, *,
                     timeout_s: float, first_pixel: int = 0) -> None:
        """PATTERN: drive pixel ``first_pixel + i`` to the raw length ``lengths_um[i]``
        (micrometres), bypassing the active table, until :meth:`end_pattern` or until
        ``timeout_s`` seconds (rounded up to 0.1 s, at most 6553.5 s) pass without another
        ``show_pattern`` to this controller (its watchdog; every call re-arms it). Pixels not
        named keep their current targets; SET_LEVEL and table pushes meanwhile move no pixel
        until the pattern ends. More pixels than one frame holds (510) go in several frames.

        Raises :class:`ControllerUnsupported` when the controller's INFO lacks the test-pattern
        feature (nothing sent), :class:`TableError` for lengths that are not a non-empty 1-D
        sequence of integers 0..max_length_um or pixels outside the controller,
        :class:`ValueError` for a timeout outside (0, 6553.5] s, :class:`NakError` when the
        controller refuses a frame, and the transient errors of :meth:`request`. Confirm
        what is shown with :meth:`read_positions` (its targets).
        """
        if not 0 < timeout_s <= MAX_PATTERN_TIMEOUT_S:
            raise ValueError(f"timeout_s must be > 0 and <= {MAX_PATTERN_TIMEOUT_S} s, got "
                             f"{timeout_s!r}")
        timeout_ds = min(0xFFFF, math.ceil(round(timeout_s * 10, 6)))
        info = self._pattern_info(address)
        where = f"controller {address} on {self.port}"
        lv = np.asarray(lengths_um)
        if (lv.ndim != 1 or lv.size == 0 or not np.issubdtype(lv.dtype, np.integer)
                or lv.min() < 0 or lv.max() > info.max_length_um):
            raise TableError(f"{where}: pattern lengths must be a non-empty 1-D sequence of "
                             f"integers 0..{info.max_length_um} um (its max_length_um)")
        if first_pixel < 0 or first_pixel + lv.size > info.n_pixels:
            raise TableError(f"{where} has pixels 0..{info.n_pixels - 1}; a pattern of "
                             f"{lv.size} from pixel {first_pixel} does not fit")
        raw = lv.astype("<u2")
        for start in range(0, raw.size, MAX_PATTERN_PIXELS):
            part = raw[start:start + MAX_PATTERN_PIXELS]
            self._expect(address, Pattern(timeout_ds, first_pixel + start, part.tobytes()), Ack)

    def end_pattern(self, address: int) -> None:
        """PATTERN_END: every pixel back to normal display at once (the table's length for the
        last levels set); harmless when no pattern is shown. Raises
        :class:`ControllerUnsupported` when the controller has no test patterns, and the
        errors of :meth:`request`."""
        self._pattern_info(address)
        self._expect(address, PatternEnd(), Ack)

    def _pattern_info(self, address: int) -> Info:
        info = self._info.get(address) or self.hello(address)
        if not info.supports_patterns:
            raise ControllerUnsupported(
                f"controller {address} on {self.port} (firmware {info.firmware_version}) has "
                f"no test patterns: its INFO lacks features bit 0 (PATTERN / PATTERN_END). "
                f"Flash firmware that has them")
        return info

    # --- table push -----------------------------------------------------------------------
    def push_table(self, address: int, table: ArrayLike,
                   table_id: int | None = None, *,
                   status: TableStatus | None = None) -> TableStatus:
        """Make ``table`` (uint16 micrometres, (256,) global or (n_pixels, 256)) active.

        Stages it chunk by chunk, commits, and reads TABLE_STATUS back. ``table_id`` defaults
        to the table's CRC-32/ISO-HDLC. Returns the status actually active afterwards, which
        carries this table's id and CRC. Raises :class:`TableError` / :class:`NakError` /
        :class:`ControllerUnsupported` for a table the controller cannot take (nothing was
        changed), and :class:`PushFailed` when transient failures outlasted every retry or the
        push ran past its wall-clock deadline (``policy.push_deadline_s``); its ``active`` is the
        status read back (the old table), or None if the controller could not be reached at
        all. The call returns within that deadline (the read-back included). ``status``: the
        controller's TABLE_STATUS the caller has just read, which the first attempt takes
        instead of reading it again (a restart reads it afresh).
        """
        final = self._push(address, table, table_id, commit=True, status=status)
        assert final is not None
        return final

    def stage_table(self, address: int, table: ArrayLike,
                    table_id: int | None = None, *,
                    status: TableStatus | None = None) -> TableStatus | None:
        """The first half of a two-phase push: HELLO, status, TABLE_BEGIN and every
        TABLE_CHUNK of ``table`` (as :meth:`push_table`, with its restarts and deadline), but
        no TABLE_COMMIT. Returns None once every byte is acknowledged (the transfer stays
        open on the controller, the old table active, until :meth:`commit_table`), or the
        active status when the controller already holds the table (nothing sent). Raises as
        :meth:`push_table` does (:class:`PushFailed`: the old table stays active); ``status``
        as for :meth:`push_table`."""
        return self._push(address, table, table_id, commit=False, status=status)

    def commit_table(self, address: int, table_id: int, table_crc: int) -> TableStatus:
        """The second half of a two-phase push (:meth:`stage_table`): TABLE_COMMIT of table
        ``table_id`` / ``table_crc`` (its CRC-32/ISO-HDLC), then TABLE_STATUS read back. No
        restart: a commit the controller refuses (it rebooted since the staging, the data it
        holds fails the CRC) or that gets no answer raises :class:`PushFailed` with the table
        read back as ``active`` (the old one), or None if the controller does not answer the
        read-back either; a permanent refusal (VALUE_RANGE) raises :class:`NakError`.
        Returns the status active afterwards, which carries this table's id and CRC."""
        tid, crc = int(table_id), int(table_crc)
        last: TransientError | None = None
        try:
            self._expect(address, TableCommit(tid, crc), Ack)
        except TransientError as exc:
            last = exc
        try:
            final = self.read_status(address, retries=self.policy.readback_retries)
        except TransientError as exc:
            raise PushFailed(f"commit of table {tid:#010x} on controller {address} on "
                             f"{self.port}: state unknown, cannot read it back ({exc}); "
                             f"earlier error: {last}", active=None, cause=exc) from None
        if _table_matches(final, tid, crc):
            return final
        raise PushFailed(f"commit of table {tid:#010x} on controller {address} on {self.port} "
                         f"failed ({last or 'another table reported after the commit'}); "
                         f"table {final.table_id:#010x} is still active", active=final,
                         cause=last)

    def _push(self, address: int, table: ArrayLike, table_id: int | None,
              commit: bool, status: TableStatus | None = None) -> TableStatus | None:
        """:meth:`push_table` (``commit``) or :meth:`stage_table` (not ``commit``); ``status``:
        the status just read, used by the first attempt."""
        arr = as_table_array(table)
        kind, n_tables = table_kind(arr)
        data = table_bytes(arr)
        crc = table_crc(arr)
        tid = crc if table_id is None else int(table_id)
        if not 0 <= tid <= 0xFFFFFFFF:
            raise TableError(f"table_id must be 0..4294967295, got {tid}")
        budget = self.policy.push_deadline_for(len(data))
        end = time.monotonic() + budget
        # the read-back of the old table keeps the time of one status request
        self._deadline = end - self._request_timeout(GetStatus())
        last: BaseException | None = None
        late: _PushDeadline | None = None
        try:
            for _ in range(self.policy.restarts + 1):
                try:
                    info = self._info.get(address) or self.hello(address)
                    self._check_fits(address, info, arr, kind, n_tables)
                    if status is None:
                        status = self.read_status(address)
                    if _table_matches(status, tid, crc):
                        return status  # already active: nothing to do
                    self._transfer(address, info, tid, kind, n_tables, data, crc, commit)
                    if not commit:
                        return None  # staged: the caller commits (commit_table)
                    break
                except _PushDeadline as exc:
                    late = exc
                    break
                except TransientError as exc:
                    last = exc
                status = None  # a restart reads it afresh
            self._deadline = end
            self._reading_back = True
            try:
                final = self.read_status(address, retries=self.policy.readback_retries)
            except TransientError as exc:
                raise PushFailed(f"push of table {tid:#010x} to controller {address} on "
                                 f"{self.port}: state unknown, cannot read it back ({exc}); "
                                 f"earlier error: {last}", active=None, cause=exc) from None
        finally:
            self._deadline = None
            self._reading_back = False
        if _table_matches(final, tid, crc):
            return final
        why = last
        if isinstance(late, _PushStopped):
            why = f"{late}; last error: {last}"
        elif late is not None:
            why = (f"not done within the push deadline of {budget:.1f} s: the controller "
                   f"answers too slowly or refuses the commit; last error: {last}")
        raise PushFailed(f"push of table {tid:#010x} to controller {address} on {self.port} "
                         f"failed ({why}); table {final.table_id:#010x} is still active",
                         active=final, cause=last)

    def _request_timeout(self, message: Message) -> float:
        """How long :meth:`request` waits for the answer to one try of ``message`` (s)."""
        expected = RESPONSE_TYPES[message.TYPE]
        answer = 12 + max(_MAX_ANSWER_PAYLOAD[expected], 6)  # header, CRC, COBS, delimiter
        return self.policy.timeout_s + self._wire_time(len(encode_frame(Frame(1, 0, message)))
                                                       + answer)

    def _check_fits(self, address: int, info: Info, arr: np.ndarray, kind: TableKind,
                    n_tables: int) -> None:
        where = f"controller {address} on {self.port}"
        least = min(self.policy.min_chunk_bytes, self.policy.chunk_bytes)
        if info.max_chunk < least:
            raise ControllerUnsupported(
                f"{where} takes table chunks of at most {info.max_chunk} bytes (max_chunk in "
                f"its INFO); this host sends no chunk smaller than {least} bytes, so that a "
                f"controller cannot stretch a push over thousands of requests. Configure the "
                f"controller with max_chunk >= {least} (the C firmware's fw_config.max_chunk, "
                f"grassfw-posix --max-chunk; 256 is the default)")
        if kind == TableKind.PER_PIXEL and n_tables != info.n_pixels:
            raise TableError(f"{where} has {info.n_pixels} pixels; per-pixel tables must have "
                             f"shape ({info.n_pixels}, 256), got {arr.shape}")
        if n_tables > info.table_capacity:
            raise TableError(f"{where} holds {info.table_capacity} tables per bank, "
                             f"got {n_tables}")
        if int(arr.max()) > info.max_length_um:
            raise TableError(f"{where} reaches at most {info.max_length_um} um of grass; the "
                             f"table asks for {int(arr.max())} um")

    def _transfer(self, address: int, info: Info, tid: int, kind: TableKind, n_tables: int,
                  data: bytes, crc: int, commit: bool = True) -> None:
        tries0 = self.quality.tries
        self._expect(address, TableBegin(tid, kind, n_tables, len(data), crc), Ack)
        size = self._send_chunks(address, info, tid, data)
        if commit:
            self._expect(address, TableCommit(tid, crc), Ack)
        self.quality.note_transfer(size, self.quality.tries - tries0)

    def _send_chunks(self, address: int, info: Info, tid: int, data: bytes) -> int:
        """Send ``data`` as TABLE_CHUNKs whose size follows the line (:mod:`~.line_quality`):
        a chunk without answer is sent again at half the size, from the same offset; only
        where it cannot shrink further are its tries limited (``chunk_floor_tries`` in a row,
        then ControllerTimeout, and the push restarts from TABLE_BEGIN; without adaptation
        ``retries`` + 1 tries, as any request). Returns the size reached."""
        p, q = self.policy, self.quality
        floor_tries = p.chunk_floor_tries if p.adaptive_chunks else p.retries + 1  # as before
        offset = failed = 0
        while offset < len(data):
            limit = self._chunk_limit(info)
            full = q.chunk_size(limit)
            size = min(full, len(data) - offset)
            try:
                self._expect(address, TableChunk(tid, offset, data[offset:offset + size]), Ack,
                             retries=0)
            except ControllerTimeout:
                q.note_chunk(False, size, tail=size < full)
                self.retransmissions += 1
                smaller = min(q.chunk_size(limit), len(data) - offset) < size
                failed = 0 if smaller else failed + 1
                if failed >= floor_tries:
                    raise ControllerTimeout(
                        f"controller {address} on {self.port}: TABLE_CHUNK at offset {offset} "
                        f"unanswered {failed} times in a row at {size}-byte chunks; check the "
                        f"address, wiring and baud rate") from None
                self._sleep(self._backoff(max(failed, 1)))
                continue
            q.note_chunk(True, size, tail=size < full)
            offset += size
            failed = 0
            if self.on_progress is not None:
                self.on_progress()
            self._check_deadline()  # also a stop request
        return q.chunk_size(self._chunk_limit(info))

    def _chunk_limit(self, info: Info) -> int:
        """The largest chunk to send now: the controller's, the policy's and :attr:`chunk_cap`
        (never below the policy's ``min_chunk_bytes``)."""
        p = self.policy
        limit = max(1, min(info.max_chunk, p.chunk_bytes))
        cap = self.chunk_cap
        if cap is not None:
            limit = min(limit, max(cap, min(p.min_chunk_bytes, limit)))
        return limit


def _levels(levels: ArrayLike) -> np.ndarray:
    """``levels`` as uint8, checked: a non-empty 1-D sequence of integers 0..255."""
    lv = np.asarray(levels)
    if (lv.ndim != 1 or lv.size == 0 or not np.issubdtype(lv.dtype, np.integer)
            or lv.min() < 0 or lv.max() > 255):
        raise TableError("levels must be a non-empty 1-D sequence of integers 0..255")
    return lv.astype(np.uint8)


def _client(port: str, baudrate: int, policy: RetryPolicy | None, **overrides) -> ControllerClient:
    policy = replace(policy or RetryPolicy(), **overrides)
    return ControllerClient(port, baudrate=baudrate, policy=policy)


def push_table(port: str, address: int, table: ArrayLike, *, table_id: int | None = None,
               baudrate: int = 115_200, policy: RetryPolicy | None = None) -> TableStatus:
    """Open ``port``, push ``table`` (um) to controller ``address``, return the active status.

    See :meth:`ControllerClient.push_table`.
    """
    with _client(port, baudrate, policy) as client:
        return client.push_table(address, table, table_id)


def read_status(port: str, address: int, *, baudrate: int = 115_200,
                policy: RetryPolicy | None = None) -> TableStatus:
    """Open ``port`` and read controller ``address``'s TABLE_STATUS (active table id and CRC)."""
    with _client(port, baudrate, policy) as client:
        return client.read_status(address)


def hello(port: str, address: int, *, baudrate: int = 115_200,
          policy: RetryPolicy | None = None) -> Info:
    """Open ``port`` and HELLO controller ``address``: its versions and capacities."""
    with _client(port, baudrate, policy) as client:
        return client.hello(address)


def scan(port: str, addresses: Iterable[int] = range(MIN_ADDRESS, MAX_ADDRESS + 1), *,
         baudrate: int = 115_200, timeout_s: float = 0.05) -> dict[int, Info]:
    """Open ``port`` and HELLO every address in ``addresses``; return those that answered."""
    with ControllerClient(port, baudrate=baudrate) as client:
        return client.scan(addresses, timeout_s=timeout_s)
