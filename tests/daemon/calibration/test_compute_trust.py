"""Who may compute for the daemon: a real dask scheduler speaking mutual TLS with a site CA
made here (tests/dask_cluster.py), workers as processes on 127.0.0.1. A worker without a
certificate of that CA cannot join; a hostile worker (a real ``dask worker`` with a preload,
grassd.rigs.dask_cluster.HOSTILE_PRELOAD) whose answer is a pickle that runs a
command when unpickled runs nothing in the daemon: it cannot join without a certificate, and
one with a certificate has its answer refused (Dask's msgpack serializer only). The same
worker on a plain tcp:// cluster, read by a Dask client with Dask's defaults, runs the command
(the attack is real). ``[compute]`` refuses tcp:// without ``allow_insecure``; a job carries
no camera password."""

from __future__ import annotations

import logging
import os
import time
from datetime import UTC, datetime
from pathlib import Path

import pytest
from daemon_harness import SITE
from dask_cluster import DaskCluster, SiteCA

from grassd.daemon.compute.config import ComputeConfig
from grassd.daemon.compute.remote import RemoteCalibrator
from grassd.daemon.compute.remote_job import CalibrationJob
from grassd.daemon.core.config.settings import default_config_text, parse_config
from grassd.daemon.core.errors import ComputeResultRefused, ComputeUnavailable, ConfigError
from grassd.sim.light_input import LightInput

pytest.importorskip("distributed")

LIGHT = LightInput(hdri=SITE, ambient_lux=6000.0, sun_lux=20000.0,
                   timestamp=datetime(2026, 6, 21, 10, tzinfo=UTC))


@pytest.fixture
def cfg(tmp_path):
    return parse_config(default_config_text(), base_dir=tmp_path)


def _wait_for_log(path: Path, needles: tuple[str, ...], timeout_s: float = 30.0) -> str:
    """The text of log ``path`` once it holds one of ``needles``."""
    deadline = time.monotonic() + timeout_s
    while True:
        text = path.read_text(errors="replace") if path.exists() else ""
        if any(n in text for n in needles):
            return text
        assert time.monotonic() < deadline, f"none of {needles} in {path}:\n{text[-3000:]}"
        time.sleep(0.2)


def _refused(cluster: DaskCluster, needle: str) -> None:
    """Wait until the scheduler's log shows a refused TLS handshake naming ``needle``."""
    _wait_for_log(cluster.logs / "scheduler.log", (needle,))


def test_a_worker_with_another_cas_certificate_cannot_join(cfg, tmp_path):
    """A real, hostile dask worker that trusts the site CA (its certificate is public) but
    presents a certificate of another CA: the scheduler refuses its handshake, it never
    joins, its pickle never reaches the daemon, whose run finds no worker."""
    mark = tmp_path / "ran"
    with DaskCluster(tmp_path / "dask") as cluster:
        preload = cluster.hostile_preload(mark)
        cert, key = SiteCA(tmp_path / "stranger", "stranger-ca").issue("stranger")
        cluster.start_worker("stranger", tls_args=[
            "--tls-ca-file", str(cluster.ca.ca_file), "--tls-cert", str(cert),
            "--tls-key", str(key)], extra=("--preload", preload))
        _refused(cluster, "CERTIFICATE_VERIFY_FAILED")
        assert "Registered to" not in (cluster.logs / "worker-stranger.log").read_text()
        assert cluster.worker_pids() == set()
        remote = RemoteCalibrator(cfg.replace(compute=cluster.compute(worker_wait_s=2.0)))
        with pytest.raises(ComputeUnavailable, match="has had no worker for"):
            remote.run(LIGHT)
        assert cluster.worker_pids() == set()
    assert not mark.exists()


def test_a_peer_without_a_certificate_cannot_connect(tmp_path):
    """Dask's own comm layer, trusting the site CA but presenting no certificate (what a
    worker without one would do): the scheduler refuses the handshake."""
    import asyncio
    import ssl

    from distributed.comm import connect

    with DaskCluster(tmp_path / "dask") as cluster:
        ctx = ssl.create_default_context(ssl.Purpose.SERVER_AUTH, cafile=cluster.ca.ca_file)
        ctx.check_hostname = False

        async def attempt() -> None:
            comm = await connect(cluster.address, timeout=5, ssl_context=ctx)
            try:  # TLS 1.3: the refusal arrives with the first read
                await comm.write({"op": "identity"})
                await comm.read()
            finally:
                comm.abort()

        with pytest.raises((OSError, ssl.SSLError)):
            asyncio.run(attempt())
        _refused(cluster, "PEER_DID_NOT_RETURN_A_CERTIFICATE")
        assert cluster.worker_pids() == set()


def test_a_hostile_worker_runs_nothing_in_the_daemon(cfg, tmp_path):
    """A worker holding a certificate of the site CA answers with a pickle that runs a
    command: the daemon's client takes answers through msgpack only, so the run is refused
    as ComputeResultRefused and the command never runs (in the daemon or anywhere)."""
    mark = tmp_path / "ran"
    with DaskCluster(tmp_path / "dask") as cluster:
        preload = cluster.hostile_preload(mark)
        cluster.add_worker("hostile", extra=("--preload", preload))
        remote = RemoteCalibrator(cfg.replace(compute=cluster.compute(worker_wait_s=5.0)))
        with pytest.raises(ComputeResultRefused, match="Dask worker tls://127.0.0.1:"):
            remote.run(LIGHT)
    assert not mark.exists(), f"the hostile pickle ran in pid {mark.read_text()}"


def test_the_same_worker_runs_its_command_in_a_client_with_dasks_defaults(tmp_path):
    """The attack is real: on a plain tcp:// cluster, a Dask client with its default
    serializers (as the daemon had) unpickles the hostile answer, and the command runs in the
    client's own process."""
    from distributed import Client

    from grassd.daemon.compute import remote

    mark = tmp_path / "ran"
    with DaskCluster(tmp_path / "dask", tls=False) as cluster:
        preload = cluster.hostile_preload(mark)
        cluster.add_worker("hostile", extra=("--preload", preload))
        with Client(cluster.address, timeout=30, set_as_default=False) as client:
            client.submit(remote.calibrate_on_worker, b"", pure=False).result(timeout=60)
    assert mark.read_text().split() == [str(os.getpid())]


def test_tcp_without_allow_insecure_is_a_config_error(tmp_path, caplog):
    base = default_config_text() + "\n[compute]\n"
    with pytest.raises(ConfigError, match=r"compute\.scheduler: tcp://calib:8786 has no TLS: "
                       r".*Use tls://host:port with tls_ca_file, tls_cert and tls_key.*"
                       r"set allow_insecure = true"):
        parse_config(base + 'scheduler = "tcp://calib:8786"\n', base_dir=tmp_path)
    (tmp_path / "ca.pem").write_text("x")
    with pytest.raises(ConfigError, match=r"compute\.tls_cert: a tls:// scheduler needs "
                       r"tls_ca_file, tls_cert, tls_key .*missing: tls_cert, tls_key"):
        parse_config(base + 'scheduler = "tls://calib:8786"\ntls_ca_file = "ca.pem"\n',
                     base_dir=tmp_path)
    with pytest.raises(ConfigError, match=r"compute\.tls_cert: .*cert\.pem is not a file"):
        parse_config(base + 'scheduler = "tls://calib:8786"\ntls_ca_file = "ca.pem"\n'
                     'tls_cert = "cert.pem"\ntls_key = "ca.pem"\n', base_dir=tmp_path)
    with pytest.raises(ConfigError, match=r"compute\.tls_ca_file: tls_ca_file is set but "
                       "tcp://calib:8786 is not a tls:// address"):
        parse_config(base + 'scheduler = "tcp://calib:8786"\nallow_insecure = true\n'
                     'tls_ca_file = "ca.pem"\n', base_dir=tmp_path)
    c = parse_config(base + 'scheduler = "tcp://calib:8786"\nallow_insecure = true\n',
                     base_dir=tmp_path)
    assert c.compute.scheduler == "tcp://calib:8786" and c.compute.allow_insecure
    # a scheduler given another way (grassd calibrate --scheduler) meets the same rule
    with pytest.raises(ConfigError, match="has no TLS"):
        RemoteCalibrator(c.replace(compute=ComputeConfig(scheduler="tcp://calib:8786")))
    with caplog.at_level(logging.WARNING, logger="grassd.daemon.compute.remote"):
        RemoteCalibrator(c)
    assert [r.getMessage() for r in caplog.records if "has no TLS" in r.getMessage()] == [
        "[compute] scheduler tcp://calib:8786 has no TLS (allow_insecure = true): anyone who "
        "can reach it can run code in this daemon; use tls:// with the site's CA "
        "(docs/operating/compute.md)"]


def test_a_job_carries_no_camera_password(tmp_path):
    """The job holds what the simulation reads: never [measure]'s or [capture]'s camera
    credentials, nor the daemon's paths."""
    text = default_config_text() + (
        '\n[capture]\ncamera = "http://192.0.2.10"\nusername = "THETA"\n'
        'password = "capture-s3cret"\n'
        '\n[measure]\ncamera = "http://192.0.2.11"\nusername = "cam"\n'
        'password = "measure-s3cret"\n')
    c = parse_config(text, base_dir=tmp_path)
    assert c.measure is not None and c.capture is not None
    job = RemoteCalibrator(c.replace(compute=ComputeConfig(
        scheduler="tcp://calib:8786", allow_insecure=True))).job(LIGHT, None)
    for secret in (b"capture-s3cret", b"measure-s3cret", b"192.0.2.1", str(tmp_path).encode()):
        assert secret not in job
    hdri = len(SITE.read_bytes())
    assert len(job) - hdri < 16 * 1024, len(job) - hdri
    assert {f for f in CalibrationJob.__dataclass_fields__} == {
        "sections", "light", "hdri", "checker", "checker_raw", "previous_um", "previous_ccm",
        "force", "previous_tables"}
