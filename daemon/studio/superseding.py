"""The simulator's side of the word it shares with the studio's server
(:mod:`grassd.sim.interrupt`).

The server process adds one to the word with every job or cancel it sends, and sends the new
value along (:mod:`grassd.daemon.studio.process`). A renderer launch in flight stops once the
word moves; before the launch is tried again, :class:`JobInterrupt` waits until the simulator
has taken in the message that moved the word, and asks the job's ``check``: a job that message
superseded ends there (``check`` raises), any other job goes on, tracing only the paths the
launch skipped. Nothing here imports Taichi: the word is a NumPy view of shared memory.
"""

from __future__ import annotations

import time

import numpy as np

from grassd.daemon.studio.worker import Check
from grassd.sim.interrupt import Interrupt

#: Seconds a stopped launch waits for the message that moved the word (it is sent right
#: after): past it, the launch goes on under the word as it is.
CATCH_UP_S: float = 1.0
#: Seconds between two looks at whether that message has been taken in.
POLL_S: float = 0.0002


class Superseding:
    """``seen`` is the word's value that came with the last job or cancel the simulator has
    taken in (given to its worker); the word itself may already be past it while a later
    message is on its way."""

    def __init__(self, word: np.ndarray) -> None:
        self.word = word
        self.seen = 0  # the server's word starts at 0 with each simulator process

    def took(self, value: int) -> None:
        """A message that moved the word to ``value`` has been taken in (they come in order)."""
        self.seen = value

    def interrupt(self, check: Check) -> JobInterrupt:
        """The renderer's :class:`~grassd.sim.interrupt.Interrupt` for a job whose ``check``
        raises once a newer job supersedes it."""
        return JobInterrupt(self, check)


class JobInterrupt(Interrupt):
    """Arms each launch of one job: waits (at most :data:`CATCH_UP_S`) until the messages
    that moved the word are taken in, then the job's ``check`` raises if one of them
    superseded it; else the launch runs under the word as taken in."""

    def __init__(self, superseding: Superseding, check: Check) -> None:
        super().__init__(superseding.word)
        self._superseding = superseding
        self._check = check

    def arm(self) -> int:
        """The word's value the launch runs under: the one taken in last, once it is the
        word's own (or the word itself after :data:`CATCH_UP_S`); raises what ``check``
        raises."""
        deadline = time.monotonic() + CATCH_UP_S
        base = self._superseding.seen
        while base != int(self.word[0]):
            if time.monotonic() > deadline:
                base = int(self.word[0])
                break
            time.sleep(POLL_S)
            base = self._superseding.seen
        self._check()
        return base
