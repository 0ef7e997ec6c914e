"""Soak benchmark: a year of light bundles through `grassd run`, with retention on.

`grassd run` (subprocess) against simulated controllers on ptys and a simulated Modbus lux
sensor, with cheap render settings, takes N bundles (default 1000) one after the other: their
manifest timestamps step through 2025 (about three a day, so 1000 bundles span a year), their
ambient lux follows the season and the hour, and their sky cycles through tiny HDRIs of
different colour and brightness. Retention is set so that it keeps only a minute of bundles
(``keep_days`` = 20 s), 20 reports and 100 runs: at this pace that is what a year does to it.

Every ``--every`` bundles it prints the daemon's resident memory (from /proc), its open file
descriptors, the state directory's size, the database's size (with its WAL), the time of a
status query over the control socket (what `grassd status` does; median of 5) and the mean
seconds per bundle over those K.
At the end it fits a line to each column after warm-up (the first 20 %) and prints the slope per
1000 bundles: flat means no leak and no growth. It prints the RSS peak of each quarter of the
bundles and the growth from the second quarter to the last, against GROWTH_MIB. With
``GRASSD_BENCH_TRACEMALLOC=DIR`` the daemon runs under tracemalloc and leaves a snapshot per row
in DIR (``python -m bench.trace_daemon diff A B`` compares two).

Run: ``python -m bench soak`` or ``python -m bench.bench_soak [--bundles N] [--every K]``.
"""

from __future__ import annotations

import argparse
import math
import os
import shutil
import sys
import time
from datetime import UTC, datetime, timedelta
from pathlib import Path

import numpy as np

from bench.daemon_process import BenchDaemon, daemon_config
from bench.trace_daemon import request_snapshot
from grassd.rigs.peak_memory import proc_mib
from grassd.sim.hdri import write_exr

SKIES = 8  #: distinct tiny HDRIs the bundles cycle through
START = datetime(2025, 1, 1, 6, 0, tzinfo=UTC)
KEEP_S = 20.0  #: retention's keep_days, in seconds: at about 0.3 s a bundle, ~70 bundles
WARM_UP = 0.2  #: fraction of the bundles left out of the fitted slopes
STATUS_QUERIES = 5  #: status queries per printed row; their median is printed
GROWTH_MIB = 16.0  #: most RSS growth from the second quarter of the bundles to the last


def _config(state: Path, cfg) -> str:
    return daemon_config(state, cfg, site="""latitude = 48.1
longitude = 11.6
timezone = "Europe/Berlin"
""", light="""lux = "manifest"
settle_s = 0
""", tail=f"""[simulation]
samples = 16
lengths = 4
[calibration]
check_levels = 3
max_rounds = 1
replicates = 2
max_jump_mm = 20.0
[retention]
keep_days = {KEEP_S / 86400:.8f}
keep_reports = 20
keep_runs = 100
""")


def _skies(d: Path) -> list[Path]:
    """SKIES tiny equirectangular HDRIs (16 x 32): a sky gradient over a ground, each with
    another colour temperature and brightness (linear Rec.709)."""
    d.mkdir(parents=True, exist_ok=True)
    out = []
    rows = np.linspace(0.0, 1.0, 16)[:, None, None]
    for k in range(SKIES):
        warm = k / (SKIES - 1)
        sky = np.array([0.6 + 0.4 * warm, 0.7, 1.0 - 0.4 * warm]) * (0.5 + k / SKIES)
        ground = np.array([0.25, 0.22, 0.15])
        img = np.where(rows < 0.5, sky * (1.5 - rows), ground) * np.ones((16, 32, 3))
        path = d / f"sky{k}.exr"
        write_exr(path, img.astype(np.float32))
        out.append(path)
    return out


def _bundle(inbox: Path, i: int, sky: Path) -> None:
    """Bundle i: light of day i * 365 / 1000 of 2025, lux by season and hour (written as an
    uploader does: hidden directory, manifest last, rename)."""
    when = START + timedelta(hours=8.76 * i)
    season = 0.5 - 0.5 * math.cos(2 * math.pi * (when.timetuple().tm_yday - 10) / 365)
    hour = when.hour + when.minute / 60
    daylight = max(0.05, math.sin(math.pi * (hour - 4) / 16)) if 4 <= hour <= 20 else 0.05
    lux = 200 + 30000 * (0.3 + 0.7 * season) * daylight
    tmp = inbox / f".b{i:05d}"
    tmp.mkdir(parents=True)
    shutil.copy(sky, tmp / "sky.exr")
    (tmp / "manifest.toml").write_text(
        f'timestamp = {when.isoformat().replace("+00:00", "Z")}\nhdri = "sky.exr"\n'
        f"ambient_lux = {lux:.1f}\n")
    os.rename(tmp, inbox / f"b{i:05d}")


def _dir_bytes(d: Path) -> int:
    total = 0
    for root, _, files in os.walk(d):
        for f in files:
            try:
                total += os.lstat(os.path.join(root, f)).st_size
            except OSError:
                pass  # pruned meanwhile
    return total


def _fds(pid: int) -> int:
    return len(os.listdir(f"/proc/{pid}/fd"))


def _slope(xs: list[float], ys: list[float]) -> float:
    """Least-squares slope of ys over xs, per 1000 xs."""
    return float(np.polyfit(np.asarray(xs, float), np.asarray(ys, float), 1)[0]) * 1000


def quarter_peaks(samples: list[tuple[int, float]], n: int) -> list[float]:
    """The largest value of each quarter of ``n`` bundles, from ``samples`` of (bundles done,
    value): a sample after bundle i lies in quarter ceil(4 i / n). A quarter without a sample
    takes the last value before it (NaN before any)."""
    peaks: list[float] = []
    for k in range(4):
        inside = [v for i, v in samples if k * n < 4 * i <= (k + 1) * n]
        before = [v for i, v in samples if 4 * i <= k * n]
        peaks.append(max(inside) if inside else before[-1] if before else math.nan)
    return peaks


def main(argv: list[str] | None = None) -> int:
    """Run the soak and print the table and the fitted slopes (``argv``: options)."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--bundles", type=int,
                    default=int(os.environ.get("GRASSD_SOAK_BUNDLES", "1000")))
    ap.add_argument("--every", type=int, default=50, help="print a row every K bundles")
    args = ap.parse_args([] if argv is None else argv)
    n, every = args.bundles, max(1, args.every)
    daemon = BenchDaemon("grassd-soak-", _config, tick_s=0.02)
    state, status, proc, log_path = daemon.state, daemon.status, daemon.proc, daemon.log
    rows: list[tuple[int, float, int, int, int, float, float]] = []
    try:
        skies = _skies(daemon.tmp / "skies")
        ready_s = daemon.wait_ready(180)
        print(f"daemon ready in {ready_s:.1f} s; {n} bundles, cheap "
              f"settings (16 samples, 4 lengths, 16x32 HDRIs), retention: {KEEP_S:g} s of bundles, "
              f"20 reports, 100 runs", flush=True)
        print(f"{'bundle':>6} {'RSS MiB':>8} {'fds':>4} {'state MiB':>9} {'db MiB':>7} "
              f"{'status ms':>9} {'s/bundle':>8} {'archive':>7} {'run rows':>9}", flush=True)
        last_id = 0
        t0 = last = time.monotonic()
        statuses: list[str] = []
        for i in range(n):
            _bundle(state / "inbox", i, skies[i % SKIES])
            while True:  # each bundle makes one run: wait until it is the newest, finished
                runs = status()["runs"]
                if runs and runs[0]["id"] > last_id and runs[0]["status"] != "running":
                    break
                if proc.poll() is not None:
                    raise RuntimeError(f"daemon exited; see {log_path}")
                time.sleep(0.01)
            last_id = runs[0]["id"]
            statuses.append(runs[0]["status"])
            if (i + 1) % every == 0 or i == 0:
                now = time.monotonic()
                per = (now - last) / (1 if i == 0 else every)  # mean over the block
                last = now
                times = []
                for _ in range(STATUS_QUERIES):
                    q0 = time.perf_counter()
                    st = status()
                    times.append(time.perf_counter() - q0)
                q_ms = float(np.median(times)) * 1e3
                db = sum(p.stat().st_size for p in state.glob("state.db*"))
                row = (i + 1, proc_mib(proc.pid), _fds(proc.pid), _dir_bytes(state), db,
                       q_ms, per)
                rows.append(row)
                if daemon.trace_dir is not None:  # GRASSD_BENCH_TRACEMALLOC: a snapshot a row
                    request_snapshot(daemon.trace_dir, f"b{i + 1:05d}")
                print(f"{row[0]:>6} {row[1]:>8.1f} {row[2]:>4} {row[3] / 2**20:>9.2f} "
                      f"{row[4] / 2**20:>7.2f} {row[5]:>9.1f} {row[6]:>8.2f} "
                      f"{st['inbox']['archive']:>7} {sum(st['run_counts'].values()):>9}",
                      flush=True)
        total = time.monotonic() - t0
        warm = [r for r in rows if r[0] > n * WARM_UP] or rows
        xs = [r[0] for r in warm]
        per_bundle = total / n
        print(f"{n} bundles in {total:.0f} s ({per_bundle:.2f} s each); runs: "
              + ", ".join(f"{s} {statuses.count(s)}" for s in sorted(set(statuses))))
        print(f"after warm-up (bundles {xs[0]}..{xs[-1]}), fitted slope per 1000 bundles: "
              f"RSS {_slope(xs, [r[1] for r in warm]):+.1f} MiB, "
              f"fds {_slope(xs, [r[2] for r in warm]):+.2f}, "
              f"state dir {_slope(xs, [r[3] / 2**20 for r in warm]):+.2f} MiB, "
              f"db {_slope(xs, [r[4] / 2**20 for r in warm]):+.2f} MiB, "
              f"status query {_slope(xs, [r[5] for r in warm]):+.2f} ms, "
              f"time per bundle {_slope(xs, [r[6] for r in warm]):+.3f} s")
        def span(k: int, scale: float = 1.0, fmt: str = ".1f") -> str:
            vals = [r[k] / scale for r in warm]
            return f"{min(vals):{fmt}}..{max(vals):{fmt}}"

        print(f"ranges after warm-up: RSS {span(1)} MiB, fds {span(2, fmt='.0f')}, state dir "
              f"{span(3, 2**20, '.2f')} MiB, db {span(4, 2**20, '.2f')} MiB, status query "
              f"{span(5)} ms, time per bundle {span(6, fmt='.2f')} s")
        quarters = quarter_peaks([(r[0], r[1]) for r in rows], n)
        print("RSS peak per quarter of the bundles: "
              + ", ".join(f"Q{k + 1} {q:.1f}" for k, q in enumerate(quarters))
              + f" MiB; growth from the second to the last quarter {quarters[3] - quarters[1]:+.1f}"
              f" MiB ({'within' if quarters[3] - quarters[1] <= GROWTH_MIB else 'OVER'} the "
              f"{GROWTH_MIB:g} MiB bound)")
    finally:
        daemon.stop()
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
