"""Child processes of the rigs, tests and benchmarks (a firmware port, QEMU, a daemon, a
studio, a Dask scheduler or worker): ended the way a service manager ends them."""

from __future__ import annotations

import os
import signal
import subprocess


def end_process(proc: subprocess.Popen, grace_s: float, *, group: bool = False) -> int:
    """End ``proc`` as a clean shutdown would: SIGTERM, then SIGKILL if it has not exited
    within ``grace_s`` seconds, and wait for it; ``group``: signal its whole process group
    (a child started with ``start_new_session=True``, and what it started). A process that has
    already exited is only reaped. Returns its exit status (negative: the signal that ended
    it, -15 for SIGTERM)."""
    if proc.poll() is None:
        send = (lambda sig: os.killpg(proc.pid, sig)) if group else proc.send_signal
        send(signal.SIGTERM)
        try:
            proc.wait(grace_s)
        except subprocess.TimeoutExpired:
            send(signal.SIGKILL)
    return proc.wait()
