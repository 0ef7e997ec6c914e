"""A camera trickling a shot is cut by the download's minimum rate (``[capture]
min_download_rate`` over ``min_download_window_s``, as curl's ``--speed-limit``) within about
one window, long before the download's deadline; an honest download is untouched. A real HTTP
server on 127.0.0.1 (grassd.rigs.hostile_camera)."""

from __future__ import annotations

import time

import pytest

from grassd.daemon.camera.client import CameraDownloadTooSlow, OscClient
from grassd.daemon.camera.config import CaptureConfig
from grassd.daemon.core.errors import CameraDownloadError
from grassd.rigs.hostile_camera import HostileServer

pytestmark = pytest.mark.timeout(60)


def _client(url: str, **kw) -> OscClient:
    return OscClient(url, timeout_s=5.0, poll_s=0.01, download_deadline_s=300.0, **kw)


def test_a_trickling_download_is_cut_in_about_a_window(tmp_path):
    with HostileServer() as srv:
        srv.trickle_s = 0.02  # 50 bytes/s, each byte well inside the per-read timeout
        cam = _client(srv.url, min_download_rate=1024, min_download_window_s=1.0)
        t0 = time.monotonic()
        with pytest.raises(CameraDownloadTooSlow, match="min_download_rate = 1024") as info:
            cam.download(f"{srv.url}/trickle-body/x.dng", tmp_path / "x.dng")
        elapsed = time.monotonic() - t0
    assert isinstance(info.value, CameraDownloadError)  # the station retries it as before
    assert 1.0 <= elapsed < 3.0, elapsed  # not the 300 s deadline
    assert srv.sent >= 10  # bytes did come
    assert list(tmp_path.iterdir()) == []
    print(f"\n50 bytes/s download: cut after {elapsed:.2f} s (window 1 s, deadline 300 s)")


def test_an_honest_download_passes_the_floor(tmp_path):
    with HostileServer() as srv:
        cam = _client(srv.url, min_download_rate=1024, min_download_window_s=1.0)
        out = cam.download(f"{srv.url}/file/x.jpg", tmp_path / "x.jpg")
    assert out.read_bytes().startswith(b"\xff\xd8")


def test_the_floor_is_configured_in_capture():
    cfg = CaptureConfig(camera="http://x", min_download_rate=2048, min_download_window_s=5.0)
    cam = OscClient.from_config(cfg)
    assert (cam.min_download_rate, cam.min_download_window_s) == (2048, 5.0)
