"""The simulator's side of the shared word (``grassd.daemon.studio.superseding``): a launch
that the word stopped is armed again only once the message that moved it is taken in, and the
job's check then decides whether the job goes on. No Taichi: the word is a NumPy array."""

from __future__ import annotations

import subprocess
import sys
import threading
import time

import numpy as np
import pytest

from grassd.daemon.studio import superseding as module
from grassd.daemon.studio.superseding import Superseding
from grassd.daemon.studio.worker import Superseded


def test_a_word_that_did_not_move_arms_at_once_under_its_value():
    checks = []
    interrupt = Superseding(np.zeros(1, np.int32)).interrupt(lambda: checks.append(1))
    t0 = time.monotonic()
    assert interrupt.arm() == 0
    assert time.monotonic() - t0 < 0.5 and checks == [1]


def test_arming_waits_for_the_message_that_moved_the_word_then_asks_the_check():
    """The server moved the word to 3 (two messages on their way); the simulator takes them in
    0.1 s later, and the second one superseded this job: ``arm`` raises what the check
    raises, after the messages are in."""
    word = np.array([3], np.int32)
    side = Superseding(word)
    side.took(1)
    stale = threading.Event()

    def check() -> None:
        if stale.is_set():
            raise Superseded("a newer request replaced this one")

    def take_in() -> None:
        time.sleep(0.1)
        side.took(2)
        stale.set()
        side.took(3)

    threading.Thread(target=take_in).start()
    t0 = time.monotonic()
    with pytest.raises(Superseded):
        side.interrupt(check).arm()
    assert time.monotonic() - t0 >= 0.09


def test_a_job_that_was_not_superseded_goes_on_under_the_new_word():
    word = np.array([0], np.int32)
    side = Superseding(word)
    interrupt = side.interrupt(lambda: None)
    word[0] = 1  # another page's input
    threading.Timer(0.05, side.took, (1,)).start()
    t0 = time.monotonic()
    assert interrupt.arm() == 1
    assert time.monotonic() - t0 < module.CATCH_UP_S  # taken in, not timed out


def test_a_message_that_never_comes_in_arms_under_the_word_after_the_catch_up_time(
        monkeypatch):
    monkeypatch.setattr(module, "CATCH_UP_S", 0.1)
    word = np.array([5], np.int32)
    t0 = time.monotonic()
    assert Superseding(word).interrupt(lambda: None).arm() == 5
    assert 0.09 <= time.monotonic() - t0 < 1.0


def test_the_module_does_not_import_taichi():
    code = ("import sys, grassd.daemon.studio.superseding, grassd.daemon.studio.process\n"
            "assert 'taichi' not in sys.modules, 'taichi imported'\n")
    subprocess.run([sys.executable, "-c", code], check=True)
