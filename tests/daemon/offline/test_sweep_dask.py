"""``grassd sweep --scheduler``: a real dask scheduler speaking mutual TLS with a site CA made
here (tests/dask_cluster.py) and two dask workers on 127.0.0.1.

Checks that a sweep over TLS (through the command line, its [compute] from --config) equals the
local sweep bit for bit, that a worker killed in the middle of a sweep loses no task, that a
sweep resumes from partial output on the cluster, that a tcp:// scheduler is refused without
``allow_insecure``, and that a hostile worker holding a valid certificate, whose answer is a
pickle that runs a command (grassd.rigs.dask_cluster.HOSTILE_PRELOAD), runs nothing in
the sweeping process and stores nothing. Every process started here is killed in teardown (its
own process group, by id).
"""

from __future__ import annotations

import logging
import os
import signal
import sqlite3
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from dask_cluster import DaskCluster, free_port

from grassd.daemon.compute.config import ComputeConfig
from grassd.daemon.core.config.settings import default_config_text
from grassd.daemon.core.errors import ComputeResultRefused, ConfigError
from grassd.daemon.offline.sweep import SweepError, SweepSpec, conditions, read_results, run_sweep

pytest.importorskip("distributed")

SPEC = SweepSpec(lengths_mm=(0.0, 10.0, 20.0), samples=256, replicates=4, latitude=48.1,
                 longitude=11.6, date="2026-03-20", timezone="Europe/Berlin")


@pytest.fixture(scope="module")
def cluster(tmp_path_factory):
    """A TLS cluster on 127.0.0.1 with workers w0 and w1 (``cluster.workers``: name -> Popen)."""
    with DaskCluster(tmp_path_factory.mktemp("dask")) as c:
        for name in ("w0", "w1"):
            c.add_worker(name)
        yield c


@pytest.fixture(scope="module")
def sky(tmp_path_factory):
    from grassd.sim.hdri import write_exr

    env = np.ones((32, 64, 3), np.float32)
    env[:16] *= 2.5
    path = tmp_path_factory.mktemp("hdri") / "sky.exr"
    write_exr(path, env)
    return str(path)


def _conds(sky):
    return conditions([sky], ["07:00", "13:00", "16:00"], [(170, 2, 0), (150, 3, 45)],
                      [("default", ()), ("splay8", (("splay_deg", 8.0),))])


N = 12  # conditions of _conds


@pytest.fixture(scope="module")
def local(sky, tmp_path_factory):
    out = tmp_path_factory.mktemp("local")
    run_sweep(SPEC, _conds(sky), out, workers=2, plots=False)
    return read_results(out / "sweep.sqlite", run_columns=False)


def _pids(cluster: DaskCluster) -> dict[int, str]:
    return {p.pid: name for name, p in cluster.workers.items()}


def _config(cluster: DaskCluster, path: Path) -> Path:
    path.write_text(default_config_text() + "\n[compute]\n" + cluster.toml())
    return path


def test_cluster_over_tls_equals_local_bit_for_bit(cluster, local, sky, tmp_path):
    """The command line, its [compute] TLS files from --config: every condition traced on
    the cluster's workers, the results equal the local sweep's."""
    from grassd.daemon.cli.main import main

    args = ["sweep", "--hdri", sky, "--time", "07:00", "--time", "13:00", "--time", "16:00",
            "--date", SPEC.date, "--latitude", "48.1", "--longitude", "11.6", "--timezone",
            SPEC.timezone, "--view", "170,2,0", "--view", "150,3,45", "--pixel", "default",
            "--pixel", "splay8:splay_deg=8", "--lengths", "0,10,20", "--samples", "256",
            "--replicates", "4", "--scheduler", cluster.address, "--config",
            str(_config(cluster, tmp_path / "grassd.toml")), "--out", str(tmp_path / "out")]
    res = CliRunner().invoke(main, args)
    assert res.exit_code == 0, res.output
    assert f"{N} computed" in res.output and f"on dask {cluster.address}" in res.output
    rows = read_results(tmp_path / "out" / "sweep.sqlite")
    used = {int(r["worker"].split(":")[1]) for r in rows}
    assert used == set(_pids(cluster))  # both cluster workers traced, none of this process
    assert read_results(tmp_path / "out" / "sweep.sqlite", run_columns=False) == local
    assert (tmp_path / "out" / "summary.png").exists()


def test_resume_partial_output_on_the_cluster(cluster, local, sky, tmp_path):
    conds = _conds(sky)
    # partial output: a local run of the first 5 conditions only
    run_sweep(SPEC, conds[:5], tmp_path, workers=1, plots=False)
    db = sqlite3.connect(tmp_path / "sweep.sqlite")
    assert db.execute("SELECT COUNT(DISTINCT key) FROM results").fetchone()[0] == 5
    db.close()
    summary = run_sweep(SPEC, conds, tmp_path, compute=cluster.compute(), plots=False)
    assert (summary.skipped, summary.computed) == (5, N - 5)
    assert read_results(tmp_path / "sweep.sqlite", run_columns=False) == local


def test_worker_killed_mid_sweep_loses_no_task(cluster, local, sky, tmp_path):
    """Last of the cluster's tests: it leaves one worker."""
    workers = _pids(cluster)
    seen: list[dict] = []
    victim: list[int] = []

    def on_result(row: dict) -> None:
        seen.append(row)
        if not victim:  # first result: kill the worker that produced it (it holds more work)
            pid = int(row["worker"].split(":")[1])
            assert pid in workers
            os.kill(pid, signal.SIGKILL)
            cluster.workers[workers[pid]].wait(10)
            victim.append(pid)

    summary = run_sweep(SPEC, _conds(sky), tmp_path, compute=cluster.compute(),
                        on_result=on_result, plots=False)
    assert victim and summary.computed == N and len(seen) == N
    # results kept arriving after the kill (it was mid-sweep), from the survivor only
    survivor = (set(workers) - set(victim)).pop()
    later = {int(r["worker"].split(":")[1]) for r in seen[4:]}  # in-flight ones aside
    assert later == {survivor}
    assert read_results(tmp_path / "sweep.sqlite", run_columns=False) == local


def test_a_hostile_worker_runs_nothing_in_the_sweep(sky, tmp_path, monkeypatch):
    """A worker holding a certificate of the site CA answers every task with a pickle that
    runs a command: the sweep's client takes answers through msgpack only, so the sweep is
    refused (ComputeResultRefused), nothing is stored and the command never runs. The attack
    is real: the same client with Dask's default deserializers runs it in this process."""
    from grassd.daemon.compute import dask_client

    mark = tmp_path / "ran"
    with DaskCluster(tmp_path / "dask") as cluster:
        cluster.add_worker("hostile", extra=("--preload", cluster.hostile_preload(mark)))
        with pytest.raises(ComputeResultRefused, match="Dask worker tls://127.0.0.1:"):
            run_sweep(SPEC, _conds(sky)[:2], tmp_path / "out", compute=cluster.compute(),
                      plots=False)
        assert not mark.exists(), f"the hostile pickle ran in pid {mark.read_text()}"
        assert read_results(tmp_path / "out" / "sweep.sqlite") == []
        monkeypatch.setattr(dask_client, "SERIALIZERS", ("dask", "pickle", "msgpack"))
        with pytest.raises(ComputeResultRefused):
            run_sweep(SPEC, _conds(sky)[:1], tmp_path / "defaults", compute=cluster.compute(),
                      plots=False)
    assert mark.read_text().split() == [str(os.getpid())]


def test_tcp_without_allow_insecure_is_refused(sky, tmp_path, caplog):
    """run_sweep and the command line refuse a tcp:// scheduler unless [compute]
    allow_insecure is true, saying how to fix it; with it, a warning (and here, no scheduler
    on the port: a clear error)."""
    from grassd.daemon.cli.main import main

    address = f"tcp://127.0.0.1:{free_port()}"
    with pytest.raises(ConfigError, match=r"compute\.scheduler: .* has no TLS: .*Use "
                       r"tls://host:port with tls_ca_file, tls_cert and tls_key"):
        run_sweep(SPEC, _conds(sky)[:1], tmp_path / "a", compute=ComputeConfig(
            scheduler=address), plots=False)
    assert not (tmp_path / "a").exists()
    config = tmp_path / "grassd.toml"
    config.write_text(default_config_text())
    res = CliRunner().invoke(main, ["sweep", "--hdri", sky, "--view", "170,2,0",
                                    "--scheduler", address, "--config", str(config),
                                    "--out", str(tmp_path / "b")])
    assert res.exit_code == 2, res.output
    assert "has no TLS" in res.output and "allow_insecure = true" in res.output
    assert not (tmp_path / "b").exists()
    with caplog.at_level(logging.WARNING), pytest.raises(SweepError,
                                                         match="cannot reach the Dask"):
        run_sweep(SPEC, _conds(sky)[:1], tmp_path / "c", compute=ComputeConfig(
            scheduler=address, allow_insecure=True, connect_timeout_s=2.0), plots=False)
    assert [r.getMessage() for r in caplog.records if "has no TLS" in r.getMessage()] == [
        f"[compute] scheduler {address} has no TLS (allow_insecure = true): anyone who can "
        "reach it can run code in this process; use tls:// with the site's CA "
        "(docs/operating/compute.md)"]


def test_unreachable_tls_scheduler_is_a_clear_error(sky, tmp_path):
    with DaskCluster(tmp_path / "dask") as cluster:
        compute = ComputeConfig(**{**cluster.compute().__dict__, "connect_timeout_s": 2.0,
                                   "scheduler": f"tls://127.0.0.1:{free_port()}"})
    with pytest.raises(SweepError, match="cannot reach the Dask scheduler"):
        run_sweep(SPEC, _conds(sky)[:1], tmp_path / "out", compute=compute, plots=False)
