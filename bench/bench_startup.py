"""Start-up and idle memory: how long the light commands take, and what an idle
daemon holds.

1. ``grassd --help``, ``grassd status`` (a state directory with a database and no daemon: the
   status read from the database) and ``grassd check-config`` (the embedded default
   configuration written to a file), each run as a whole process (the console script next to
   this Python) ``--runs`` times after one warm-up, warm (page cache and bytecode cached, in a
   temporary ``PYTHONPYCACHEPREFIX``): min and median wall seconds, and of the CPU seconds
   (user + system; on a machine shared with other work, wall time includes waiting for a
   core). Targets: 0.3 s, 0.3 s and 0.5 s.
2. The resident memory (``VmRSS``) of an idle ``grassd run``, with an empty inbox and no
   scheduled run, once it answers on its control socket and 3 s later: ``grassd run
   --simulate-hardware`` (the simulated controllers and lux sensor in the daemon's process)
   and ``grassd run`` against simulated hardware in this process (the daemon alone); each with
   local simulation (Taichi initialised at start) and without (``[compute] scheduler``, where
   the tree knows it). Target without local simulation: 150 MiB. The line also names the heavy
   libraries whose shared objects the daemon has mapped (``/proc/PID/maps``).

To compare with another tree (the figures before a change), put a tree whose ``grassd``
package is laid out as installed first on ``PYTHONPATH``: the subprocesses inherit it.

Run: ``python -m bench startup`` or ``python -m bench.bench_startup [--runs N]``.
"""

from __future__ import annotations

import argparse
import os
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from bench.daemon_process import CACHE, BenchDaemon, daemon_config, wait_ready
from grassd.rigs.peak_memory import proc_mib
from grassd.rigs.processes import end_process

GRASSD = str(Path(sys.executable).parent / "grassd")
#: shared objects whose presence in a daemon's memory map means a heavy library was imported
HEAVY = ("taichi", "matplotlib", "pandas", "scipy", "PIL")


def _times_s(argv: list[str], runs: int, env: dict[str, str]
             ) -> tuple[list[float], list[float]]:
    """(wall seconds, CPU seconds: user + system) of ``runs`` runs of ``argv`` (after one
    warm-up run) in environment ``env``; RuntimeError when one fails."""
    wall, cpu = [], []
    for i in range(runs + 1):
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        t0 = time.perf_counter()
        proc = subprocess.run(argv, capture_output=True, text=True, timeout=120, env=env)
        dt = time.perf_counter() - t0
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        if proc.returncode != 0:
            raise RuntimeError(f"{' '.join(argv)} failed: {proc.stderr[-2000:]}")
        if i:
            wall.append(dt)
            cpu.append(after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime)
    return wall, cpu


def _state_with_database(state: Path) -> None:
    """A state directory holding an empty history database, as after a daemon's first start."""
    from grassd.daemon.core.store.history import History
    from grassd.daemon.core.store.layout import StateLayout

    db = StateLayout(state).db
    db.parent.mkdir(parents=True, exist_ok=True)
    with History(db):
        pass


def startup_times(runs: int) -> None:
    """Print min and median wall seconds of the three light commands."""
    from grassd.daemon.core.config.settings import default_config_text

    tmp = Path(tempfile.mkdtemp(prefix="grassd-bench-startup-"))
    try:
        config = tmp / "grassd.toml"
        config.write_text(default_config_text())
        _state_with_database(tmp / "state")
        commands = {
            "grassd --help": ([GRASSD, "--help"], 0.3),
            "grassd status": ([GRASSD, "status", "--config", str(config), "--state-dir",
                               str(tmp / "state")], 0.3),
            "grassd check-config": ([GRASSD, "check-config", "--config", str(config)], 0.5),
        }
        # warm: the bytecode cached, as pip leaves an installed grassd (not in the tree: in a
        # temporary prefix, and even where PYTHONDONTWRITEBYTECODE is set)
        env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
        env["PYTHONPYCACHEPREFIX"] = str(tmp / "pycache")
        for name, (argv, target_s) in commands.items():
            wall, cpu = _times_s(argv, runs, env)
            print(f"{name:20s} wall min {min(wall):.3f} s, median {statistics.median(wall):.3f} "
                  f"s; CPU min {min(cpu):.3f} s, median {statistics.median(cpu):.3f} s (target "
                  f"{target_s} s; {runs} warm runs)", flush=True)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def _mapped_heavy(pid: int) -> list[str]:
    """Which of :data:`HEAVY` have a file mapped into process ``pid``."""
    maps = Path(f"/proc/{pid}/maps").read_text()
    return [name for name in HEAVY if f"/{name}" in maps]


def _report_rss(label: str, pid: int) -> None:
    ready = proc_mib(pid)
    time.sleep(3.0)
    heavy = _mapped_heavy(pid)
    print(f"{label}: RSS {ready:.0f} MiB when ready, {proc_mib(pid):.0f} MiB 3 s later "
          f"(target 150 MiB); heavy libraries mapped: {', '.join(heavy) or 'none'}", flush=True)


#: ``[compute]``: the simulations on a Dask scheduler (none listens: an idle daemon never asks)
REMOTE = '[compute]\nscheduler = "tcp://127.0.0.1:8786"\n'


def _has_compute_table() -> bool:
    """Whether the ``grassd`` that the subprocesses run knows ``[compute]`` (a tree from
    before it does not)."""
    code = ("import dataclasses; from grassd.daemon.core.config.settings import Config; "
            "print('compute' in {f.name for f in dataclasses.fields(Config)})")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=120, cwd=tempfile.gettempdir())
    return proc.stdout.strip() == "True"


def _where(remote: bool) -> str:
    return ("no local simulation ([compute] scheduler)" if remote
            else "local simulation (Taichi initialised at start)")


def rss_simulate_hardware(remote: bool) -> None:
    """RSS of an idle ``grassd run --simulate-hardware`` (embedded default site), its
    simulations here or (``remote``) on a Dask scheduler."""
    from grassd.daemon.core.config.settings import default_config_text, load_config

    tmp = Path(tempfile.mkdtemp(prefix="grassd-bench-rss-"))
    config = tmp / "grassd.toml"
    config.write_text(f'state_dir = "{tmp / "state"}"\ncache_dir = "{CACHE}"\n'
                      + default_config_text().replace("interval_s = 3600.0", "interval_s = 0")
                      + (REMOTE if remote else ""))
    sock = load_config(config).control_socket
    log = tmp / "daemon.log"
    with open(log, "w") as err:
        proc = subprocess.Popen([GRASSD, "run", "--config", str(config), "--simulate-hardware",
                                 "--tick", "0.2"], stdout=subprocess.DEVNULL, stderr=err)
    try:
        ready_s = wait_ready(sock, proc, log, 120)
        _report_rss(f"grassd run --simulate-hardware, {_where(remote)}, idle (ready in "
                    f"{ready_s:.1f} s)", proc.pid)
    finally:
        end_process(proc, 60)
        shutil.rmtree(tmp, ignore_errors=True)


def rss_daemon_alone(remote: bool) -> None:
    """RSS of an idle ``grassd run`` whose simulated hardware runs in this process, its
    simulations here or (``remote``) on a Dask scheduler."""
    daemon = BenchDaemon("grassd-bench-rss-", lambda state, cfg: daemon_config(
        state, cfg, light=f"""lux = "modbus"
[light.modbus]
port = {cfg.light.modbus.port}
words = 2
scale = 0.1
""", tail=REMOTE if remote else ""), tick_s=0.2)
    try:
        ready_s = daemon.wait_ready(120)
        _report_rss(f"grassd run, hardware in another process, {_where(remote)}, idle (ready "
                    f"in {ready_s:.1f} s)", daemon.proc.pid)
    finally:
        daemon.stop()


def main(argv: list[str] | None = None) -> None:
    """Run the benchmark and print the numbers."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=int(os.environ.get("GRASSD_BENCH_RUNS", "10")),
                    help="warm runs of each command (default 10)")
    args = ap.parse_args([] if argv is None else argv)
    startup_times(args.runs)
    remote = _has_compute_table()
    if not remote:
        print("this grassd has no [compute] table: idle RSS with local simulation only")
    for where in (False, True) if remote else (False,):
        rss_simulate_hardware(where)
        rss_daemon_alone(where)


if __name__ == "__main__":
    main(sys.argv[1:])
