"""One line, several threads: the BusLock serves waiters in the order they came (a push that
lets go between two chunks gets the line back after the frame that waited), and one client
shared by threads answers each its own requests (the Python model on a pty)."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from grassd.firmware_proto.bus_lock import BusLock
from grassd.firmware_proto.client import ControllerClient
from grassd.rigs.simulator import start_buses


def test_waiters_get_the_line_in_arrival_order():
    lock, order = BusLock(), []
    lock.acquire()
    threads = []
    for k in range(5):
        def take(k=k):
            with lock:
                order.append(k)
        t = threading.Thread(target=take)
        t.start()
        threads.append(t)
        while lock.waiting < k + 1:  # k is queued before k + 1 starts
            time.sleep(0.001)
    lock.release()
    for t in threads:
        t.join(5)
    assert order == [0, 1, 2, 3, 4]


def test_a_holder_that_lets_go_queues_behind_the_waiter():
    """The push's pattern: request, release, request again; the frame waiting in between is
    served between the two."""
    lock, order = BusLock(), []
    lock.acquire()
    waiter = threading.Thread(target=lambda: (lock.acquire(), order.append("frame"),
                                              lock.release()))
    waiter.start()
    while lock.waiting < 1:
        time.sleep(0.001)
    lock.release()
    with lock:
        order.append("chunk")
    waiter.join(5)
    assert order == ["frame", "chunk"]


def test_reentrant_and_owned():
    lock = BusLock()
    with lock, lock:
        pass
    with pytest.raises(RuntimeError, match="does not hold"):
        lock.release()


def test_threads_share_one_client(tmp_path):
    (bus,) = start_buses(tmp_path / "s", 1, link_dir=tmp_path, n_pixels=8)
    table = np.arange(256, dtype=np.uint16) * 60
    errors: list[BaseException] = []
    try:
        with ControllerClient(bus.path) as client:
            def levels():
                try:
                    for k in range(60):
                        client.set_levels(1, np.full(8, k))
                except BaseException as exc:  # noqa: BLE001 - reported below
                    errors.append(exc)

            client.push_table(1, table)
            t = threading.Thread(target=levels)
            t.start()
            status = client.push_table(1, np.flip(table), table_id=9)
            t.join(10)
            assert not errors, errors
            assert status.table_id == 9
            assert client.retransmissions == 0 and client.stale_frames == 0
            client.set_levels(1, np.full(8, 59))  # after the commit: the new table's
            pos = client.read_positions(1, 0, 8)
            assert np.array_equal(pos[:, 1], np.flip(table)[np.full(8, 59)])
    finally:
        bus.stop()
