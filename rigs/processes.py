"""Child processes of the rigs, tests and benchmarks (a firmware port, QEMU, a daemon, a
studio): ended the way a service manager ends them."""

from __future__ import annotations

import subprocess


def end_process(proc: subprocess.Popen, grace_s: float) -> int:
    """End ``proc`` as a clean shutdown would: SIGTERM, then SIGKILL if it has not exited
    within ``grace_s`` seconds, and wait for it. A process that has already exited is only
    reaped. Returns its exit status (negative: the signal that ended it, -15 for SIGTERM)."""
    if proc.poll() is None:
        proc.terminate()
        try:
            proc.wait(grace_s)
        except subprocess.TimeoutExpired:
            proc.kill()
    return proc.wait()
