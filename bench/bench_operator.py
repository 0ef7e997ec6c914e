"""Operator's view benchmark: what the daemon spends after a reconcile (health, metrics textfile)
and after a run (status page) on a state database as full as retention lets it get: 5000 runs
(``[retention] keep_runs``) and 10000 bundles in the ingest journal. Prints milliseconds per
call and the sizes of what is written."""

from __future__ import annotations

import json
import sqlite3
import tempfile
import time
from pathlib import Path

import numpy as np

from grassd.daemon.core.config.settings import load_default_config
from grassd.daemon.core.monitoring.metrics import registry, write_textfile
from grassd.daemon.core.monitoring.status_page import render, write_page
from grassd.daemon.core.runtime.service import collect_status
from grassd.daemon.core.store.history import History

RUNS = 5000
BUNDLES = 10000


def _fill(db: Path, cfg) -> None:
    """Bulk-insert RUNS ok runs (every 20th rejected) and BUNDLES journal rows of every
    outcome, and the controllers in sync with the last table."""
    History(db).close()  # the schema
    rng = np.random.default_rng(1)
    t0 = time.time() - RUNS * 3600.0
    table = json.dumps(list(range(0, 20000, 79))[:256])
    runs = []
    for i in range(1, RUNS + 1):
        ok = i % 20 != 0
        m = {"r2_closed_loop": 0.999 - 0.002 * rng.random(), "max_dev_de00": rng.random(),
             "ogcd_range_de00": 20 + 3 * rng.random()} if ok else {}
        runs.append((i, t0 + i * 3600, t0 + i * 3600 + 30, "bundle", None, "{}",
                     float(rng.uniform(100, 100000)), "manifest", "ok" if ok else "rejected",
                     None if ok else "bad HDRI", json.dumps(m), i if ok else None,
                     1234 if ok else None, table if ok else None, None, None, None))
    reasons = (None, "superseded: older light", "HDRI is not an OpenEXR file",
               "abandoned after 3 attempts")
    journal = [(f"h{i:08d}", f"b{i:08d}", f"bundle-{i}", "rejected" if i % 4 >= 2 else
                "archived", reasons[i % 4], None, 1, t0 + i * 300, t0 + i * 300)
               for i in range(BUNDLES)]
    with sqlite3.connect(db) as c:
        c.executemany(f"INSERT INTO runs VALUES ({','.join('?' * 17)})", runs)
        c.executemany(f"INSERT INTO journal VALUES ({','.join('?' * 9)})", journal)
        last = max(r[0] for r in runs if r[8] == "ok")
        c.executemany("INSERT INTO controllers VALUES (?, ?, 1234, 1, ?, NULL, ?)",
                      [(x.name, last, time.time(), time.time()) for x in cfg.controllers])


def _time(f, n: int) -> float:
    f()
    t0 = time.perf_counter()
    for _ in range(n):
        f()
    return (time.perf_counter() - t0) / n * 1000


def main() -> None:
    """Run the benchmark and print the numbers."""
    tmp = Path(tempfile.mkdtemp(prefix="grassd-bench-operator-"))
    cfg = load_default_config(state_dir=tmp)
    _fill(tmp / "state.db", cfg)
    prom, page = tmp / "grassd.prom", tmp / "index.html"
    with History(tmp / "state.db") as h:
        status = collect_status(h, cfg)

        def after_reconcile() -> None:
            st = collect_status(h, cfg)
            write_textfile(prom, registry(st, h))

        def after_run() -> None:
            write_page(page, render(status, h, timezone="UTC"))

        ms_rec = _time(after_reconcile, 20)
        ms_run = _time(after_run, 5)
    print(f"state database: {RUNS} runs, {BUNDLES} journal rows, "
          f"{len(cfg.controllers)} controllers")
    print(f"after a reconcile (status, health, metrics textfile): {ms_rec:.1f} ms "
          f"(textfile {prom.stat().st_size} bytes)")
    print(f"after a run (status page with {RUNS} runs' trends): {ms_run:.1f} ms "
          f"(page {page.stat().st_size / 1024:.0f} KiB)")
