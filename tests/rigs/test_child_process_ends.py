"""A rig's child process ends as a service manager ends it: SIGTERM, SIGKILL after the grace
period, always reaped (grassd.rigs.processes)."""

from __future__ import annotations

import subprocess
import sys
import time

from grassd.rigs.processes import end_process


def _python(code: str) -> subprocess.Popen:
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    assert proc.stdout.readline() == "up\n"  # its signal handlers are in place
    return proc


def test_a_process_that_heeds_sigterm_ends_with_it():
    proc = _python("import time; print('up', flush=True); time.sleep(60)")
    assert end_process(proc, 5.0) == -15


def test_a_process_that_ignores_sigterm_is_killed_after_the_grace_period():
    proc = _python("import signal, time; signal.signal(signal.SIGTERM, signal.SIG_IGN); "
                   "print('up', flush=True); time.sleep(60)")
    t0 = time.monotonic()
    assert end_process(proc, 0.5) == -9
    assert 0.5 <= time.monotonic() - t0 < 5.0


def test_a_process_that_already_exited_keeps_its_status():
    proc = _python("print('up', flush=True); raise SystemExit(3)")
    proc.stdout.read()
    assert end_process(proc, 5.0) == 3
