"""`grassd run` with ``[compute] scheduler``: a daemon that cannot import Taichi (as on Linux
aarch64) calibrates on a real dask scheduler and worker (processes on 127.0.0.1,
tests/dask_cluster.py) against simulated controllers (``--simulate-hardware``). The worker is
killed in the middle of a run: the active table stays, health turns degraded with the reason,
the bundle waits in processing/ (neither lost nor rejected), and once a worker is back the
retry makes the new table."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
from pathlib import Path

import pytest
from daemon_harness import CACHE, ONE_VIEW, display_2x2, drop, service, tick_until, write_config
from daemon_harness import wait_for as harness_wait_for
from dask_cluster import DaskCluster

from grassd.daemon.core.errors import ControlError
from grassd.daemon.core.runtime.control import request

pytest.importorskip("distributed")
pytestmark = [pytest.mark.slow, pytest.mark.long]

#: `grassd` in a Python where ``import taichi`` fails, as where Taichi has no wheels
NO_TAICHI = ("import sys; sys.modules['taichi'] = None; "
             "from grassd.daemon.cli.main import main; main()")

#: 1024 paths a replicate, so that a run lasts long enough for the test to see it on the worker
#: (polled every 20 ms) and kill the worker before it ends: with 64, once Taichi's small
#: launches used both cores, a run on the warm worker was committed within 1.5 s of its bundle
#: and the test (then polling every 0.2 s) missed it once in four full runs
CONFIG = display_2x2(
    viewpoints=ONE_VIEW + "[[viewpoints]]\nh_cm = 160\nd_m = 2\ntheta_deg = 30\nweight = 0.5\n",
    samples=1024, seed=5, replicates=2, layouts=2, max_rounds=2,
    extra='[compute]\n{compute}connect_timeout_s = 5.0\nworker_wait_s = 5.0\n')


def wait_for(cond, timeout_s: float, what: str, log: Path, poll: float = 0.2):
    """:func:`daemon_harness.wait_for` with the daemon log's tail in its failure."""
    return harness_wait_for(cond, timeout_s, what, poll=poll,
                            context=lambda: "daemon log:\n"
                            + log.read_text(errors="replace")[-4000:])


def test_worker_killed_mid_run_keeps_the_table_and_the_retry_succeeds(tmp_path):
    from distributed import Client

    log = tmp_path / "daemon.log"
    with DaskCluster(tmp_path / "dask", cache_dir=CACHE) as cluster:
        cluster.add_worker("w1")
        config = tmp_path / "grassd.toml"
        config.write_text(CONFIG.format(compute=cluster.toml()))
        sock = tmp_path / "state" / "control.sock"
        with open(log, "wb") as out:
            daemon = subprocess.Popen(
                [sys.executable, "-c", NO_TAICHI, "run", "--config", str(config),
                 "--simulate-hardware", "--tick", "0.2", "--log-level", "info"],
                stdout=out, stderr=subprocess.STDOUT, start_new_session=True)
        try:
            def status() -> dict | None:
                assert daemon.poll() is None, log.read_text(errors="replace")[-4000:]
                try:
                    return request(sock, {"cmd": "status"}, timeout_s=10)["status"]
                except ControlError:
                    return None

            wait_for(status, 60, "the daemon's control socket", log)
            inbox = tmp_path / "state" / "inbox"
            drop(inbox, "b1", lux=6000.0, timestamp="2026-06-21T10:00:00+02:00")
            first = wait_for(lambda: (s := status()) and s["health"] == "ok"
                             and s["desired_table"] and s, 240, "the first table", log)
            table = first["desired_table"]
            assert first["run_counts"]["ok"] == 1

            # a second bundle; its run starts on w1 (a run lasts seconds on a warm worker),
            # which dies as soon as the scheduler shows the run on it
            with Client(cluster.address, timeout=10, set_as_default=False,
                        security=cluster.security()) as client:
                drop(inbox, "b2", lux=9000.0, timestamp="2026-06-21T11:00:00+02:00")
                wait_for(lambda: any(k.startswith("grassd-calibrate-")
                                     for keys in client.processing().values() for k in keys),
                         60, "the second run on the Dask worker", log, poll=0.02)
                cluster.kill_worker("w1")

            waiting = wait_for(lambda: (s := status()) and s["waiting_bundles"] and s, 60,
                               "the bundle waiting after the worker died", log)
            [w] = waiting["waiting_bundles"]
            # the daemon saw the run on w1 and w1 leave, or (killed before its first look)
            # the cluster without a worker for worker_wait_s
            assert w["bundle"] == "b2"
            assert re.search(r"Dask worker tls://127\.0\.0\.1:\d+ died or left during the run"
                             r"|has had no worker for \d+ s", w["reason"]), w["reason"]
            assert waiting["health"].startswith("degraded: ")
            assert f"bundle b2 waits: {w['reason']}" in waiting["health"]
            assert waiting["desired_table"] == table  # the last good table stays active
            assert all(c["in_sync"] and c["table_id"] == table["table_id"]
                       for c in waiting["controllers"])
            assert waiting["inbox"]["processing"] == 1 and waiting["inbox"]["rejected"] == 0
            assert waiting["run_counts"]["rejected"] == 0

            cluster.add_worker("w2")  # the retry (backoff 30 s) finds a worker again
            done = wait_for(lambda: (s := status()) and s["health"] == "ok"
                            and s["desired_table"]["table_id"] != table["table_id"] and s,
                            240, "the retried run's table", log)
            assert done["waiting_bundles"] == [] and done["run_counts"]["ok"] == 2
            assert done["inbox"] == {"inbox": 0, "processing": 0, "archive": 2, "rejected": 0}
            assert all(c["in_sync"] and c["table_id"] == done["desired_table"]["table_id"]
                       for c in done["controllers"])
        finally:
            if daemon.poll() is None:
                os.killpg(daemon.pid, signal.SIGTERM)
                try:
                    assert daemon.wait(30) == 0
                except subprocess.TimeoutExpired:
                    os.killpg(daemon.pid, signal.SIGKILL)
                    daemon.wait(10)
    text = log.read_text(errors="replace")
    assert "Traceback" not in text and "initialising the renderer" not in text


def test_a_run_without_a_bundle_waits_for_compute_with_health_degraded(tmp_path, hw):
    """A scheduled run (no bundle to leave waiting) on a cluster whose worker died: the run
    fails without a rejection, the last good table stays active, health says degraded with
    the reason, the main loop retries it with backoff, and once a worker is back the retry
    makes the new table and health is ok again. An in-process daemon on simulated hardware."""
    sim, cfg = hw
    with DaskCluster(tmp_path / "dask", cache_dir=CACHE) as cluster:
        cluster.add_worker("w1")
        path = write_config(tmp_path / "g.toml", tmp_path / "state", cfg, extra=(
            f'[compute]\n{cluster.toml()}connect_timeout_s = 5.0\nworker_wait_s = 2.0\n'))
        svc = service(path, retry_s=1.0, retry_max_s=2.0)
        try:
            drop(svc.cfg.light.inbox, "b1", lux=1000.0)
            svc.tick()
            table = svc.history.current_table()
            assert table is not None and svc.status().health.level == "ok"

            cluster.kill_worker("w1")
            out = svc.scheduled_run("interval")
            assert out.status == "failed" and out.retry_in_s == 1.0, out
            st = svc.status()
            assert st.daemon.compute_wait.attempts == 1
            assert st.health.level == "degraded"
            [reason] = st.health.reasons
            assert reason.startswith("interval run waits for compute (1 failed, retry in 1 s): ")
            assert re.search(r"died or left during the run|has had no worker for \d+ s", reason)
            assert svc.history.current_table().id == table.id  # the last good table stays
            assert all(c.in_sync and c.table_id == table.id for c in st.controllers)
            assert st.run_counts.rejected == 0 and st.run_counts.failed == 1

            # the main loop retries it (backoff 1 s, then 2 s) while no worker is there
            tick_until(svc, lambda: svc.status().daemon.compute_wait.attempts == 2, timeout=60)
            assert svc.status().daemon.compute_wait.retry_in_s <= 2.0

            cluster.add_worker("w2")
            tick_until(svc, lambda: svc.status().daemon.compute_wait is None, timeout=240)
            st = svc.status()
            assert st.health.level == "ok", st.health
            assert st.desired_table.table_id != table.id and st.run_counts.ok == 2
            assert st.runs[0].trigger == "interval" and st.runs[0].status == "ok"
        finally:
            svc.shutdown()
