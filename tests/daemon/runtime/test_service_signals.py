"""SIGTERM, SIGINT and SIGHUP never hang the daemon: the handlers only note the
signal and write a byte to a self-pipe; a relay thread sets the stop and reload events
(grassd.daemon.core.runtime.signal_relay).

Seen before: a daemon hung in its SIGTERM handler, which called ``stop_event.set()`` while the
main loop waited on that event: Python runs a handler in the main thread between two bytecodes,
also while ``Event.wait`` holds the lock of the event's condition, and ``set()`` then waits for
a lock its own thread holds. Each check runs in a process of its own with a timeout, so a
deadlock fails the test instead of hanging CI.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import pytest
from test_grassd_run_end_to_end import Daemon, manifest, wait_for

#: the main thread holds the event's lock, as inside Event.wait, when the signal arrives
LOCK_HELD = """
import signal, sys, threading
stop, reload = threading.Event(), threading.Event()
if sys.argv[1] == "relay":
    from grassd.daemon.core.runtime.signal_relay import SignalRelay
    relay = SignalRelay({signal.SIGTERM: stop.set, signal.SIGINT: stop.set,
                         signal.SIGHUP: reload.set},
                        latched=(signal.SIGTERM, signal.SIGINT)).install()
else:  # what the service did before
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    signal.signal(signal.SIGHUP, lambda *_: reload.set())
with stop._cond, reload._cond:
    for _ in range(100):
        signal.raise_signal(signal.SIGHUP)
    signal.raise_signal(signal.SIGTERM)  # the handler runs here, in this thread
    print("handlers returned while the locks were held", flush=True)
assert stop.wait(10) and reload.wait(10), "the relay did not set the events"
if sys.argv[1] == "relay":
    reload.clear()
    signal.raise_signal(signal.SIGHUP)
    assert reload.wait(10)
    relay.close(restore=True)
    assert signal.getsignal(signal.SIGTERM) is signal.SIG_DFL
print("ok")
"""


def test_a_signal_while_the_event_lock_is_held_does_not_deadlock():
    r = subprocess.run([sys.executable, "-c", LOCK_HELD, "relay"], capture_output=True,
                       text=True, timeout=60, check=False)
    assert r.returncode == 0 and r.stdout.splitlines() == [
        "handlers returned while the locks were held", "ok"], r.stderr


def test_a_handler_that_sets_the_event_itself_deadlocks_under_the_lock():
    """The hazard the relay removes is real: a handler that sets the event itself never
    returns (killed after 5 s)."""
    with pytest.raises(subprocess.TimeoutExpired):
        subprocess.run([sys.executable, "-c", LOCK_HELD, "event"], capture_output=True,
                       timeout=5, check=False)


def test_a_signal_storm_still_stops_the_daemon(tmp_path):
    """A real `grassd run`: hundreds of SIGHUPs as fast as they can be sent leave it running
    and answering; then SIGHUPs and SIGTERMs interleaved stop it cleanly, within a bound."""
    d = Daemon(tmp_path)
    try:
        d.start()
        d.drop("first", manifest(1, lux=3000.0))
        wait_for(lambda: d.status()["run_counts"]["ok"] == 1, 120, "a first run", d)
        pid = d.proc.pid
        for _ in range(500):
            os.kill(pid, signal.SIGHUP)
        assert d.status()["activity"] is not None  # still answers
        d.drop("second", manifest(2, lux=3000.0))
        wait_for(lambda: d.status()["run_counts"]["ok"] == 2, 120, "a run after the storm", d)
        t0 = time.monotonic()
        for i in range(400):
            os.kill(pid, signal.SIGTERM if i % 4 == 3 else signal.SIGHUP)
        rc = d.proc.wait(60)  # raises TimeoutExpired (the test fails) when it hangs
        stopped_s = time.monotonic() - t0
        d.proc = None
        print(f"\n  stopped {stopped_s:.2f} s after the first SIGTERM of the storm")
        assert rc == 0
        d.drain()
        assert any("STOPPING=1" in m for m in d.messages)
    finally:
        d.close()
