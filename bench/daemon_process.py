"""A `grassd run` subprocess for the daemon benchmarks: started on simulated hardware in a
temporary directory, its status over the control socket, waiting until it answers, and
stopping it with everything it made."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

from bench.trace_daemon import ENV
from bench.trace_daemon import command as trace_command
from grassd.daemon.core.config.settings import load_default_config
from grassd.daemon.core.errors import DaemonNotRunning
from grassd.daemon.core.runtime.control import request
from grassd.rigs.processes import end_process
from grassd.rigs.simulated_site import SimulatedHardware, hardware_toml

ROOT = Path(__file__).resolve().parents[1]
#: the Taichi kernel cache the benchmarks' daemons share (as `make` sets it)
CACHE = os.environ.get("GRASSD_CACHE_DIR", str(ROOT / ".venv" / "grassd-cache"))
#: Tokyo, the embedded default's site
TOKYO = "latitude = 35.0\nlongitude = 139.0\n"


def daemon_config(state: Path, cfg: object, *, light: str, tail: str, site: str = TOKYO) -> str:
    """A benchmark daemon's configuration (TOML): ``state`` and the shared kernel cache,
    ``site`` ([site] keys), the simulated hardware of ``cfg``, the paper's reference viewpoint,
    the inbox with ``light`` (more [light] keys and tables), no scheduled runs, then ``tail``
    (the [simulation], [calibration], ... tables)."""
    return f"""state_dir = "{state}"
cache_dir = "{CACHE}"
[site]
{site}{hardware_toml(cfg)}[[viewpoints]]
h_cm = 170
d_m = 2
[light]
inbox = "inbox"
{light}[schedule]
interval_s = 0
{tail}"""


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


class BenchDaemon:
    """``grassd run --tick TICK`` on a config ``config(state_dir, hardware_config)`` (TOML
    text) and simulated hardware (3000 lux), all under a fresh temporary directory ``tmp``;
    its stderr goes to ``log``. :meth:`stop` ends it and removes the directory. With
    ``GRASSD_BENCH_TRACEMALLOC=DIR`` it runs under tracemalloc (:mod:`bench.trace_daemon`)."""

    def __init__(self, prefix: str, config: Callable[[Path, object], str],
                 tick_s: float) -> None:
        self.tmp = Path(tempfile.mkdtemp(prefix=prefix))
        self.hw = SimulatedHardware(load_default_config(), self.tmp / "hw", lux=3000.0)
        cfg = self.hw.start()
        self.state = self.tmp / "state"
        self.sock = self.state / "control.sock"
        self.log = self.tmp / "daemon.log"
        conf = self.tmp / "grassd.toml"
        conf.write_text(config(self.state, cfg))
        args = ["run", "--config", str(conf), "--tick", str(tick_s)]
        #: where the daemon serves tracemalloc snapshots (bench.trace_daemon), or None
        self.trace_dir = Path(os.environ[ENV]) if os.environ.get(ENV) else None
        cmd = ([str(Path(sys.executable).parent / "grassd"), *args] if self.trace_dir is None
               else trace_command(str(self.trace_dir), args))
        with open(self.log, "w") as err:
            self.proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=err,
                                         cwd=ROOT if self.trace_dir else None)

    def status(self) -> dict:
        """The daemon's status (:func:`status`)."""
        return status(self.sock)

    def wait_ready(self, limit_s: float) -> float:
        """Seconds until it answers (:func:`wait_ready`)."""
        return wait_ready(self.sock, self.proc, self.log, limit_s)

    def stop(self) -> None:
        """SIGTERM, then SIGKILL after 60 s; stop the hardware; remove the directory."""
        end_process(self.proc, 60)
        self.hw.stop()
        shutil.rmtree(self.tmp, ignore_errors=True)
