"""Daemon benchmark: 100 bundles in a row through `grassd run` (subprocess) against simulated
controllers on ptys and a simulated Modbus lux sensor; prints seconds per bundle and the
daemon's resident memory (RSS) along the way, so a leak shows as a rising column."""

from __future__ import annotations

import os
import shutil
import time
from pathlib import Path

from bench.daemon_process import BenchDaemon, daemon_config
from grassd.sim.hdri import default_site_hdri

BUNDLES = int(os.environ.get("GRASSD_BENCH_BUNDLES", "100"))
def _config(state: Path, cfg) -> str:
    return daemon_config(state, cfg, light=f"""lux = "modbus"
settle_s = 0.1
[light.modbus]
port = {cfg.light.modbus.port}
words = 2
scale = 0.1
""", tail="""[simulation]
samples = 256
lengths = 9
[calibration]
check_levels = 9
max_rounds = 2
replicates = 4
max_jump_mm = 20.0
""")


def main() -> None:
    """Run the benchmark and print the numbers."""
    site = default_site_hdri()
    daemon = BenchDaemon("grassd-bench-", _config, tick_s=0.1)
    state, status = daemon.state, daemon.status
    try:
        ready_s = daemon.wait_ready(120)
        print(f"daemon ready in {ready_s:.1f} s")
        print(f"{'bundle':>6} {'s/bundle':>9} {'RSS MiB':>8}")
        t0 = time.monotonic()
        last, last_i = t0, 0
        for i in range(BUNDLES):
            d = state / "inbox" / f".b{i}"
            d.mkdir(parents=True)
            shutil.copy(site, d / "sky.exr")
            # light times grow with i: older light than the active table's is superseded
            (d / "manifest.toml").write_text(
                f'timestamp = 2026-06-21T10:{i // 60:02d}:{i % 60:02d}+09:00\n'
                f'hdri = "sky.exr"\nambient_lux = {1000 + i}\n')
            os.rename(d, state / "inbox" / f"b{i:03d}")
            while True:  # one status request per poll (it was asked twice)
                counts = status()["run_counts"]
                if counts["ok"] + counts["rejected"] >= i + 1:
                    break
                time.sleep(0.05)
            if i in (0, 9, 24, 49, 74, BUNDLES - 1):
                now = time.monotonic()
                per = (now - last) / (i + 1 - last_i)
                print(f"{i + 1:>6} {per:>9.2f} {status()['rss_mb']:>8.1f}", flush=True)
                last, last_i = now, i + 1
        total = time.monotonic() - t0
        # A run is counted once its table is recorded; its push to the controllers may still
        # be under way, so wait (at most 30 s) for every controller to report it.
        t_sync = time.monotonic()
        while (st := status())["health"] != "ok" and time.monotonic() - t_sync < 30:
            time.sleep(0.1)
        print(f"{BUNDLES} bundles in {total:.1f} s ({total / BUNDLES:.2f} s each); "
              f"runs ok {st['run_counts']['ok']}, health {st['health']} "
              f"{time.monotonic() - t_sync:.1f} s after the last run was recorded")
    finally:
        daemon.stop()


if __name__ == "__main__":
    main()
