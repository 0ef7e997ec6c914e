"""The arm64 tier: ``grassd run --simulate-hardware`` on a Debian arm64 root under qemu-user
(tests/arm64/arm64_root.py), grassd installed there from this checkout by the root's pip without
Taichi, its calibrations on an x86 Dask worker on this host (``[compute] scheduler``). One
bundle dropped into its inbox must become a table active on its simulated controllers, as
``grassd status --json`` run in the root reports.

Skipped with one line where debootstrap or qemu-user-static is missing or we are not root
(``.ci/run`` installs them). Cold (no root, no wheels) it costs a few minutes more than warm:
docs/operating/arm64.md states both.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import time
from pathlib import Path

import pytest
from arm64_root import (
    ENV,
    PYTHON,
    VENV,
    ensure_root,
    in_root,
    install_grassd,
    missing_reason,
    run_in_root,
)
from daemon_harness import CACHE, display_2x2, drop, wait_for

from grassd.daemon.core.errors import DaemonNotRunning
from grassd.daemon.core.runtime.control import request

REASON = missing_reason()
pytestmark = [pytest.mark.slow, pytest.mark.long, pytest.mark.timeout(3000)]
if REASON is not None:
    pytestmark.append(pytest.mark.skip(reason=REASON))

#: the test's directory as the arm64 daemon sees it (bound in from the host)
SITE_DIR = "/mnt/site"

#: a 2 x 2 display on two controllers (one bus each), lux from the manifest, few samples: the
#: run itself takes seconds on the worker
CONFIG = display_2x2(
    'state_dir = "state"\ncache_dir = "cache"\n'
    '[site]\nlatitude = 48.1\nlongitude = 11.6\ntimezone = "Europe/Berlin"\n',
    ports=("/dev/grassd-arm64-bus0", "/dev/grassd-arm64-bus1"), samples=64,
    replicates=2, layouts=2,
    extra='[compute]\nscheduler = "{scheduler}"\nallow_insecure = true\nconnect_timeout_s = 60\n'
          "worker_wait_s = 120\n")


def _status(sock: Path) -> dict | None:
    """The running daemon's status over its control socket (asked from the host), or None."""
    try:
        return request(sock, {"cmd": "status"}, timeout_s=60)["status"]
    except (DaemonNotRunning, OSError):
        return None


def _active_everywhere(st: dict | None) -> bool:
    """A table is wanted and every controller reports it active (in sync)."""
    return bool(st and st["desired_table"] and st["controllers"]
                and all(c["in_sync"] for c in st["controllers"]))


def test_bundle_becomes_active_on_arm64_daemon_computing_on_x86_worker(tmp_path):
    from dask_cluster import DaskCluster

    t0 = time.monotonic()
    times = {"root": ensure_root()}
    times.update(install_grassd(tmp_path / "install"))
    # the root is arm64, and its grassd has no renderer of its own
    probe = run_in_root([PYTHON, "-c", "import importlib.util, platform; "
                         "print(platform.machine(), importlib.util.find_spec('taichi'))"])
    assert probe.stdout.split() == ["aarch64", "None"]

    site = tmp_path / "site"
    site.mkdir()
    binds = {site: SITE_DIR}
    log = site / "daemon.log"
    # plain tcp:// (allow_insecure): the root's paths differ from the host's, and TLS has
    # tests of its own (tests/daemon/calibration/test_compute_trust.py)
    with DaskCluster(tmp_path / "dask", cache_dir=CACHE, tls=False) as cluster:
        cluster.add_worker("x86")
        (site / "grassd.toml").write_text(CONFIG.format(scheduler=cluster.address))
        grassd = [PYTHON, f"{VENV}/bin/grassd"]
        conf = ["--config", f"{SITE_DIR}/grassd.toml"]
        t = time.monotonic()
        with open(log, "ab") as out:
            daemon = subprocess.Popen(in_root([*grassd, "run", *conf, "--simulate-hardware",
                                               "--tick", "0.5"], binds),
                                      env=ENV, stdout=out, stderr=subprocess.STDOUT)
        try:
            def alive() -> None:
                assert daemon.poll() is None, \
                    f"arm64 daemon exited with {daemon.returncode}:\n{log.read_text()[-4000:]}"

            def tail() -> str:
                return log.read_text()[-4000:]

            sock = site / "state" / "control.sock"
            wait_for(lambda: _status(sock), 600, "the arm64 daemon's control socket",
                     poll=1, check=alive, context=tail)
            times["daemon start"] = time.monotonic() - t
            t = time.monotonic()
            drop(site / "state" / "inbox", "b1", lux=1000.0)
            wait_for(lambda: _active_everywhere(_status(sock)), 900,
                     "a table active on every simulated controller", poll=2, check=alive,
                     context=tail)
            times["bundle to active table"] = time.monotonic() - t
            t = time.monotonic()
            st = json.loads(run_in_root([*grassd, "status", "--json", *conf], binds).stdout)
            times["grassd status"] = time.monotonic() - t
            table = st["desired_table"]
            assert table is not None and len(st["controllers"]) == 2
            for c in st["controllers"]:
                assert c["in_sync"] and c["table_id"] == table["table_id"], c
            assert [r["status"] for r in st["runs"]] == ["ok"]
            assert st["health"] == "ok", st["health"]
        finally:
            if daemon.poll() is None:
                daemon.send_signal(signal.SIGTERM)
                try:
                    daemon.wait(120)
                except subprocess.TimeoutExpired:
                    os.kill(daemon.pid, signal.SIGKILL)
                    daemon.wait(30)
        assert daemon.returncode == 0, tail()
    times["total"] = time.monotonic() - t0
    print("arm64 tier: " + ", ".join(f"{k} {v:.0f} s" for k, v in times.items()))
