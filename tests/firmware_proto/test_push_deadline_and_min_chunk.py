"""A hostile controller on the bus cannot hold the host: a push ends within its wall-clock
deadline (the old table stays active, the daemon's fleet reports it), a long push reports
progress per chunk and ends at once when the daemon stops, and a controller that asks for tiny
chunks is refused before anything is sent. Over a real pseudo-terminal."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from grassd.firmware_proto.client import (
    MIN_PUSH_BYTES_PER_S,
    PUSH_DEADLINE_S,
    ControllerClient,
    ControllerUnsupported,
    RetryPolicy,
)
from grassd.firmware_proto.errors import PushFailed
from grassd.firmware_proto.messages import Message, Nak, NakCode, TableChunk, TableCommit
from grassd.rigs.firmware import Controller, simulated_config
from grassd.rigs.simulator import SimulatedBus

pytestmark = pytest.mark.timeout(60)

N_PIXELS = 4
#: request timeout margin of the host in these tests, and how long the controller waits before
#: it answers a chunk: just inside it, as the attack does
TIMEOUT_S = 0.1
STALL_S = 0.08
DEADLINE_S = 1.5
#: what the push may run past its deadline: pyserial's poll period (5 ms), thread switches
#: on a loaded machine (the structure itself ends it by the deadline)
SLACK_S = 1.0


class StallingController(Controller):
    """While ``hostile``: answers every TABLE_CHUNK ``stall_s`` late (just before the host's
    timeout) and refuses every commit with CRC_MISMATCH, a NAK the host restarts after."""

    def __init__(self, *args, stall_s: float = STALL_S, **kw) -> None:
        super().__init__(*args, **kw)
        self.stall_s = stall_s
        self.hostile = False
        self.chunks = self.commits = 0

    def _chunk(self, m: TableChunk) -> Message:
        if self.hostile:
            self.chunks += 1
            time.sleep(self.stall_s)
        return super()._chunk(m)

    def _commit(self, m: TableCommit) -> Message:
        if self.hostile:
            self.commits += 1
            return Nak(m.TYPE, NakCode.CRC_MISMATCH, 0)
        return super()._commit(m)


def _table(seed: int, shape: tuple[int, ...] = (N_PIXELS, 256)) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 20001, shape).astype(np.uint16)


def _policy(**kw) -> RetryPolicy:
    # restarts: enough that the deadline, not their count, ends the push; the deadline of
    # every table size is DEADLINE_S (no allowance per byte) unless a test sets one
    kw.setdefault("min_push_bytes_per_s", 1e9)
    kw.setdefault("push_deadline_s", DEADLINE_S)
    return RetryPolicy(timeout_s=TIMEOUT_S, retries=2, backoff_s=0.005, restarts=20, **kw)


@pytest.fixture
def stalling(tmp_path):
    """A StallingController (address 1, 4 pixels, 16-byte chunks) alone on a pty."""
    ctl = StallingController(simulated_config(1, n_pixels=N_PIXELS, max_chunk=16),
                             tmp_path / "controller-1.eeprom")
    with SimulatedBus([ctl], link_path=tmp_path / "ttyGRASS0") as bus:
        yield bus, ctl
        assert bus.errors == 0


def test_deadline_grows_with_the_table_beyond_the_base():
    p = RetryPolicy()
    assert p.push_deadline_for(512) == PUSH_DEADLINE_S == 25.0  # one global table
    # 16 per-pixel tables: 83-173 s measured on a line with 1 % byte errors at 115200 baud
    assert p.push_deadline_for(16 * 512) == 16 * 512 / MIN_PUSH_BYTES_PER_S > 173
    with pytest.raises(ValueError, match="push_deadline_s"):
        RetryPolicy(push_deadline_s=0)
    with pytest.raises(ValueError, match="min_push_bytes_per_s"):
        RetryPolicy(min_push_bytes_per_s=0)


def test_a_slow_push_reports_progress_per_chunk_and_ends_when_the_daemon_stops(stalling):
    bus, ctl = stalling
    ctl.stall_s = 0.01
    stop = threading.Event()
    chunks: list[float] = []

    def progress():
        chunks.append(time.monotonic())
        if len(chunks) == 20:
            stop.set()  # SIGTERM arrives in the middle of the transfer

    with ControllerClient(bus.path, policy=_policy(push_deadline_s=30.0), seed=3) as client:
        assert client.push_table(1, _table(1), table_id=1).table_id == 1
        client.on_progress, client.cancel = progress, stop
        ctl.hostile = True
        t0 = time.monotonic()
        with pytest.raises(PushFailed) as exc:
            client.push_table(1, _table(2), table_id=2)
        held_s = time.monotonic() - t0
    assert len(chunks) == 20 and held_s < 5.0, held_s  # not the 30 s deadline
    assert "stopped" in str(exc.value) and exc.value.active.table_id == 1
    assert np.array_equal(ctl.active_table(), _table(1))


@pytest.mark.parametrize("shape, stall_s, commits", [
    ((N_PIXELS, 256), STALL_S, 0),  # 128 chunks of 80 ms: ~10 s a transfer, x21 without
    ((256,), 0.02, 1),  # 32 chunks of 20 ms, commit refused, restarted: 21 x 0.7 s without
])
def test_a_stalling_controller_that_refuses_commits_is_given_up_on_at_the_deadline(
        stalling, shape, stall_s, commits):
    bus, ctl = stalling
    ctl.stall_s = stall_s
    old, new = _table(1, shape), _table(2, shape)
    with ControllerClient(bus.path, policy=_policy(), seed=3) as client:
        assert client.push_table(1, old, table_id=1).table_id == 1
        ctl.hostile = True
        t0 = time.monotonic()
        with pytest.raises(PushFailed) as exc:
            client.push_table(1, new, table_id=2)
        held_s = time.monotonic() - t0
        assert DEADLINE_S - 0.3 < held_s <= DEADLINE_S + SLACK_S, held_s
        assert ctl.chunks >= 10 and ctl.commits >= commits  # it did stall, and refuse
        assert "push deadline of 1.5 s" in str(exc.value)
        assert exc.value.active is not None and exc.value.active.table_id == 1
        assert np.array_equal(ctl.active_table(), old)  # the last good table stays active
        # the same client pushes again once the controller behaves; the deadline cut did not
        # count as a bad line (chunks stay at the controller's 16 bytes, no shrink below it)
        ctl.hostile = False
        assert client.push_table(1, new, table_id=2).table_id == 2
        assert client.quality.chunk_size(16) == 16
    assert np.array_equal(ctl.active_table(), new)


def test_the_daemons_fleet_reports_the_stalled_push_and_keeps_the_old_table(stalling):
    from grassd.daemon.core.config.settings import ControllerConfig
    from grassd.daemon.core.hardware.fleet import Fleet

    bus, ctl = stalling
    cfg = ControllerConfig(bus.path, address=1, pixels=((0, N_PIXELS - 1),))
    with Fleet([cfg], policy=_policy()) as fleet:
        assert fleet.push(_table(1), 1)[0].ok
        ctl.hostile = True
        t0 = time.monotonic()
        (report,) = fleet.push(_table(2), 2)
        held_s = time.monotonic() - t0
    # the fleet reads the status first (one request) and then pushes once
    assert held_s <= DEADLINE_S + TIMEOUT_S + SLACK_S, held_s
    assert not report.ok and report.reachable and report.pushed
    assert report.table_id == 1 and "push deadline" in report.error
    assert np.array_equal(ctl.active_table(), _table(1))


@pytest.mark.parametrize("max_chunk", [1, 8, 15])
def test_a_controller_asking_for_tiny_chunks_is_refused_before_any_transfer(tmp_path,
                                                                            max_chunk):
    ctl = Controller(simulated_config(1, n_pixels=N_PIXELS, max_chunk=max_chunk),
                     tmp_path / "controller-1.eeprom")
    with SimulatedBus([ctl], link_path=tmp_path / "tty") as bus, \
            ControllerClient(bus.path, policy=_policy()) as client:
        t0 = time.monotonic()
        with pytest.raises(ControllerUnsupported) as exc:
            client.push_table(1, _table(1), table_id=1)
        assert time.monotonic() - t0 < 1.0
        frames = bus.frames
    msg = str(exc.value)
    assert f"at most {max_chunk} bytes" in msg and "max_chunk >= 16" in msg
    assert frames == 1  # HELLO only: no TABLE_BEGIN, no chunk
    assert ctl.active_table() is None


def test_16_byte_chunks_are_still_taken(tmp_path):
    ctl = Controller(simulated_config(1, n_pixels=1, max_chunk=16), tmp_path / "c.eeprom")
    with SimulatedBus([ctl], link_path=tmp_path / "tty") as bus, \
            ControllerClient(bus.path, policy=_policy()) as client:
        t = np.arange(256, dtype=np.uint16) * 50
        assert client.push_table(1, t, table_id=5).table_id == 5
    assert np.array_equal(ctl.active_table(), t)
