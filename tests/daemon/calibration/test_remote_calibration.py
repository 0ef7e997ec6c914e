"""``[compute] scheduler``: a calibration run on a real dask scheduler and worker (processes on
127.0.0.1, tests/dask_cluster.py) equals the same run here bit for bit; a scheduler that does
not answer and a cluster without workers are :class:`ComputeUnavailable`, never a rejection."""

from __future__ import annotations

import json
import time
from dataclasses import replace
from datetime import UTC, datetime

import numpy as np
import pytest
from daemon_harness import CACHE, HEAD, SITE
from dask_cluster import DaskCluster, free_port

from grassd.calib.charts import get_chart
from grassd.calib.colour_spaces import (
    prophoto_to_xyz,
    rec709_to_prophoto,
    xyz_d50_to_d65,
    xyz_to_rec709,
)
from grassd.calib.dng import DngCamera, write_linear_dng
from grassd.daemon.compute.feature import ComputeFeature
from grassd.daemon.compute.remote import RemoteCalibrator
from grassd.daemon.core.calibration.calibrate import Calibrator, init_backend
from grassd.daemon.core.config.settings import ComputeConfig, parse_config
from grassd.daemon.core.errors import ComputeUnavailable, ConfigError
from grassd.daemon.core.store.manifest import CheckerPhoto
from grassd.sim.light_input import LightInput

pytest.importorskip("distributed")

#: a 2 x 2 display on one controller, two viewpoints, few samples: one run takes seconds
SMALL = HEAD + """[display]
rows = 2
cols = 2
[[controllers]]
port = "/dev/null"
[[viewpoints]]
h_cm = 170
d_m = 2
[[viewpoints]]
h_cm = 160
d_m = 2
theta_deg = 30
weight = 0.5
[light]
inbox = "inbox"
[simulation]
samples = 64
seed = 5
lengths = 5
layouts = 2
[calibration]
replicates = 2
check_levels = 5
max_rounds = 2
max_jump_mm = 20.0
"""

LIGHT = LightInput(hdri=SITE, ambient_lux=6000.0, sun_lux=20000.0,
                   timestamp=datetime(2026, 6, 21, 10, tzinfo=UTC))


def _without_timings(d):
    """``d`` (a report) without its wall times, which differ from run to run."""
    if isinstance(d, dict):
        return {k: _without_timings(v) for k, v in d.items() if k != "seconds"}
    if isinstance(d, list):
        return [_without_timings(v) for v in d]
    return d


def _checker(tmp_path) -> CheckerPhoto:
    """A real linear DNG of a SpyderCHECKR 24 seen at an angle, and its corners."""
    chart = get_chart("spydercheckr-24")
    corners = ((40.0, 30.0), (260.0, 45.0), (250.0, 175.0), (30.0, 165.0))
    from grassd.calib.regions import apply_homography, homography

    h, w = 200, 300
    uv = apply_homography(homography(np.array(corners), [(0, 0), (1, 0), (1, 1), (0, 1)]),
                          np.stack(np.mgrid[0:h, 0:w][::-1], axis=-1) + 0.5)
    col, row = np.floor(uv[..., 0] * 6).astype(int), np.floor(uv[..., 1] * 4).astype(int)
    img = np.full((h, w, 3), 0.05)
    inside = (uv >= 0).all(-1) & (uv < 1).all(-1)
    albedo = rec709_to_prophoto(np.clip(xyz_to_rec709(prophoto_to_xyz(chart.prophoto())), 0,
                                        None))  # within the camera's gamut
    img[inside] = 0.02 + 0.45 * albedo[(np.clip(row, 0, 3) * 6 + np.clip(col, 0, 5))[inside]]
    dng = write_linear_dng(tmp_path / "chart.dng", xyz_d50_to_d65(prophoto_to_xyz(img)),
                           DngCamera(), exposure=0.8)
    return CheckerPhoto(dng, corners)


@pytest.fixture
def cfg(tmp_path):
    c = parse_config(SMALL, base_dir=tmp_path)
    init_backend(c)
    return c


def test_cluster_run_equals_local_run_bit_for_bit(cfg, tmp_path):
    checker = _checker(tmp_path)
    previous = np.linspace(0, 20000, 256).astype(np.uint16)
    local = Calibrator(cfg).run(LIGHT, checker=checker, previous_um=previous)
    with DaskCluster(tmp_path / "dask", cache_dir=CACHE) as cluster:
        cluster.add_worker("w1")
        remote_cfg = cfg.replace(compute=cluster.compute())
        calibrator = ComputeFeature().calibrator(remote_cfg)
        assert isinstance(calibrator, RemoteCalibrator)
        seen: list[str] = []
        remote = calibrator.run(LIGHT, checker=checker, previous_um=previous,
                                progress=seen.append)
    assert remote.ccm_source == local.ccm_source == "bundle"  # the RAW travelled as bytes
    assert np.array_equal(remote.table_um, local.table_um)
    assert np.array_equal(remote.ccm.matrix, local.ccm.matrix)
    assert (json.dumps(_without_timings(remote.report()), sort_keys=True)
            == json.dumps(_without_timings(local.report()), sort_keys=True))
    assert any("on Dask worker tls://127.0.0.1:" in s for s in seen)


def test_unreachable_scheduler_is_compute_unavailable(cfg):
    remote = RemoteCalibrator(cfg.replace(compute=ComputeConfig(
        scheduler=f"tcp://127.0.0.1:{free_port()}", allow_insecure=True, connect_timeout_s=1.0)))
    t0 = time.monotonic()
    with pytest.raises(ComputeUnavailable, match="cannot reach the Dask scheduler at tcp://"):
        remote.run(LIGHT)
    assert time.monotonic() - t0 < 20


def test_cluster_without_workers_is_compute_unavailable_after_the_wait(cfg, tmp_path):
    with DaskCluster(tmp_path / "dask") as cluster:
        remote = RemoteCalibrator(cfg.replace(compute=cluster.compute(worker_wait_s=2.0)))
        with pytest.raises(ComputeUnavailable, match="has had no worker for"):
            remote.run(LIGHT)


def test_bad_input_is_rejected_on_the_worker_as_here(cfg, tmp_path):
    """What the run itself raises (here: light the lighting refuses) comes back as it is, so
    the daemon rejects such a bundle as it would after a local run."""
    from grassd.sim.errors import SimError

    bad = replace(LIGHT, ambient_lux=-5.0)
    with pytest.raises(SimError) as here:
        Calibrator(cfg).run(bad)
    with DaskCluster(tmp_path / "dask", cache_dir=CACHE) as cluster:
        cluster.add_worker("w1")
        remote = RemoteCalibrator(cfg.replace(compute=cluster.compute()))
        with pytest.raises(SimError) as there:
            remote.run(bad)
    assert type(there.value) is type(here.value) and str(there.value) == str(here.value)


@pytest.mark.parametrize("address", ["127.0.0.1:8786", "tcp://host", "http://host:8786"])
def test_compute_scheduler_must_be_an_address(address, tmp_path):
    with pytest.raises(ConfigError, match=r"compute\.scheduler: must be a Dask scheduler"):
        parse_config(SMALL + f'[compute]\nscheduler = "{address}"\n', base_dir=tmp_path)
    c = parse_config(SMALL + '[compute]\nscheduler = "tcp://calib:8786"\nallow_insecure = true\n',
                     base_dir=tmp_path)
    assert c.compute.scheduler == "tcp://calib:8786"
