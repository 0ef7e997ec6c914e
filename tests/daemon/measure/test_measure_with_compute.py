"""A measurement on a daemon whose runs go to a Dask cluster (``[compute] scheduler``, a real
TLS scheduler and worker on 127.0.0.1): the uncorrected tables are computed on the worker, the
pixel models from the camera here (this computer's Taichi, their light built here), and the
measurement ends accepted with its corrected tables pushed. Before, the models asked the
remote calibrator for their light, which it has not: every such measurement failed after its
photos (this test then fails with that AttributeError). The measurement also initialises the
renderer here itself now; that half this test cannot show, as the simulated camera renders its
photos in this process and has initialised Taichi already."""

from __future__ import annotations

from pathlib import Path

import pytest
from daemon_harness import CACHE, write_config
from dask_cluster import DaskCluster

from grassd.daemon.cli.features import daemon_features
from grassd.daemon.compute.remote import RemoteCalibrator
from grassd.daemon.core.config.settings import load_config, load_default_config
from grassd.daemon.core.runtime.service import Service
from grassd.daemon.measure.cli import simulated_setup, start_measuring_camera
from grassd.rigs.simulated_site import SimulatedHardware

pytest.importorskip("distributed")
pytestmark = [pytest.mark.slow, pytest.mark.long]

SECRET = Path(__file__).resolve().parents[2] / "data" / "measure" / "secret_variation.toml"


def test_a_measurement_with_its_runs_on_a_dask_cluster_is_accepted(tmp_path):
    sim = SimulatedHardware(load_default_config(), tmp_path / "hw", lux=2500.0)
    cfg = sim.start()
    display, camera = start_measuring_camera(sim, cfg, str(SECRET), 2500.0, samples=256)
    try:
        with DaskCluster(tmp_path / "dask", cache_dir=CACHE) as cluster:
            cluster.add_worker("w1")
            path = write_config(tmp_path / "grassd.toml", tmp_path / "state", cfg, extra=(
                f'[measure]\ncamera = "{camera.url}"\npattern_timeout_s = 30\nsettle_s = 10.0\n'
                "samples = 256\nlayouts = 1\npatterns = 4\n"
                f"[compute]\n{cluster.toml()}worker_wait_s = 60.0\n"))
            svc = Service(load_config(path), features=daemon_features())
            try:
                assert isinstance(svc.calibrator, RemoteCalibrator)
                first = svc.one_shot()  # on the worker: this process has no renderer yet
                assert first.status.value == "ok", first
                simulated_setup(svc.cfg, display, camera.url, 2500.0)
                report = svc.features.get("measure").now(svc)
            finally:
                svc.shutdown()
        assert report["status"] == "ok", report.get("error")
        assert report["tables"]["status"] == "ok" and all(report["tables"]["pushed"])
        assert report["uniformity"]["after"] < report["uniformity"]["before"]
    finally:
        camera.stop()
        sim.stop()
