"""A `grassd run` subprocess for the daemon benchmarks: its status over the control socket, and
waiting until it answers."""

from __future__ import annotations

import subprocess
import time
from pathlib import Path

from grassd.daemon.errors import DaemonNotRunning
from grassd.daemon.runtime.control import request


def status(sock: Path) -> dict:
    """The daemon's ``status`` over its control socket ``sock``."""
    return request(sock, {"cmd": "status"}, timeout_s=60)["status"]


def wait_ready(sock: Path, proc: subprocess.Popen, log: Path, limit_s: float) -> float:
    """Wait until the daemon ``proc`` answers on ``sock``; seconds it took. RuntimeError (naming
    ``log``) when it exits first or takes longer than ``limit_s`` seconds."""
    t0 = time.monotonic()
    while True:
        try:
            status(sock)
            return time.monotonic() - t0
        except DaemonNotRunning:
            if time.monotonic() - t0 > limit_s or proc.poll() is not None:
                raise RuntimeError(f"daemon did not start; see {log}") from None
            time.sleep(0.2)
