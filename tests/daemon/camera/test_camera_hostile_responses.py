"""The OSC camera client against a hostile camera (or anyone on its Wi-Fi): a real HTTP server on
127.0.0.1 that redirects elsewhere, sends a 300 MiB body, trickles one byte a second, or sends
nonsense. Each ends in a typed CameraError within a bound of time and memory; nothing else is
contacted, nothing is left on disk."""

from __future__ import annotations

import socket
import threading
import time
import tracemalloc

import pytest

from grassd.daemon.camera.client import OscClient
from grassd.daemon.camera.config import CaptureConfig
from grassd.daemon.core.errors import (
    CameraDownloadError,
    CameraHttpError,
    CameraProtocolError,
    CameraUnreachable,
    CaptureError,
)
from grassd.rigs.hostile_camera import HUGE, HostileServer, MiB
from grassd.rigs.peak_memory import peak_rss_growth

pytestmark = pytest.mark.timeout(60)

@pytest.fixture
def hostile():
    with HostileServer() as srv:
        yield srv


def client(url: str, **kw) -> OscClient:
    kw.setdefault("timeout_s", 5.0)
    return OscClient(url, poll_s=0.01, **kw)


def test_errors_stay_retryable_capture_errors():
    """The station retries every CaptureError: the new failures must stay of that family."""
    for cls in (CameraUnreachable, CameraProtocolError, CameraDownloadError, CameraHttpError):
        assert issubclass(cls, CaptureError)


def test_config_defaults_reach_the_client():
    cfg = CaptureConfig(camera="http://127.0.0.1:9")
    cli = OscClient.from_config(cfg)
    assert (cli.request_deadline_s, cli.download_deadline_s) == (
        cfg.request_deadline_s, cfg.download_deadline_s)
    assert (cli.max_json_bytes, cli.max_download_bytes) == (
        cfg.max_json_bytes, cfg.max_download_bytes)
    assert cfg.max_json_bytes < cfg.max_download_bytes < HUGE


# --------------------------------------------------------------------------- redirects


def test_redirect_to_another_host_is_refused_and_never_followed(hostile):
    with HostileServer() as elsewhere:
        hostile.redirect_to = f"{elsewhere.url}/osc/info"
        cam = client(f"{hostile.url}/redirect")
        with pytest.raises(CameraHttpError) as err:
            cam.info()
        assert elsewhere.hits == []  # nothing went to the other host
    msg = str(err.value)
    assert err.value.status == 302
    assert "redirect" in msg and "another scheme or port" in msg and elsewhere.url in msg
    assert "follows no redirects" in msg


def test_redirect_to_a_named_host_says_so(hostile):
    hostile.redirect_to = "http://attacker.example/osc/info"
    with pytest.raises(CameraHttpError, match="redirect to another host"):
        client(f"{hostile.url}/redirect").state()


def test_redirect_of_a_download_is_refused_and_leaves_no_file(hostile, tmp_path):
    with HostileServer() as elsewhere:
        hostile.redirect_to = f"{elsewhere.url}/shot.jpg"
        cam = client(hostile.url)
        with pytest.raises(CameraHttpError, match="redirect"):
            cam.download(f"{hostile.url}/redirect/shot.jpg", tmp_path / "shot.jpg")
        assert elsewhere.hits == []
    assert list(tmp_path.iterdir()) == []


def test_same_host_redirect_is_refused_too(hostile):
    hostile.redirect_to = "/osc/elsewhere"
    with pytest.raises(CameraHttpError, match="redirect to another path"):
        client(f"{hostile.url}/redirect").info()
    assert hostile.hits == ["/redirect/osc/info"]


# --------------------------------------------------------------------------- byte caps


def _peak(fn):
    """(exception raised by fn, seconds, peak Python allocation, peak RSS growth), the
    sizes in bytes."""
    tracemalloc.start()
    try:
        raised, seconds, rss = peak_rss_growth(fn, every_s=0.005)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    return raised, seconds, peak, rss


def test_huge_json_answer_stops_at_the_cap(hostile):
    cam = client(f"{hostile.url}/huge")
    exc, seconds, peak, rss = _peak(cam.state)
    assert isinstance(exc, CameraProtocolError), exc
    assert f"cap of {cam.max_json_bytes} bytes" in str(exc)
    assert peak < cam.max_json_bytes + 8 * MiB
    assert rss < 32 * MiB
    time.sleep(0.2)
    # the server got rid of at most the cap plus what the socket buffers hold
    assert hostile.sent < cam.max_json_bytes + 16 * MiB
    assert seconds < 5


def test_declared_huge_json_answer_is_refused_before_reading(hostile):
    cam = client(f"{hostile.url}/huge-declared")
    exc, seconds, peak, _ = _peak(cam.info)
    assert isinstance(exc, CameraProtocolError), exc
    assert f"announces {HUGE} bytes" in str(exc)
    assert peak < 4 * MiB and seconds < 5


def test_huge_error_body_is_not_read(hostile):
    cam = client(f"{hostile.url}/huge-error")
    exc, seconds, peak, _ = _peak(cam.info)
    assert isinstance(exc, CameraHttpError) and exc.status == 500, exc
    assert peak < 4 * MiB and seconds < 5


@pytest.mark.parametrize("mode", ["huge", "huge-declared"])
def test_huge_download_stops_at_the_cap_and_leaves_nothing(hostile, tmp_path, mode):
    cam = client(hostile.url)  # the default download cap, 128 MiB
    dest = tmp_path / "shot.jpg"
    exc, seconds, peak, rss = _peak(lambda: cam.download(f"{hostile.url}/{mode}/x.jpg", dest))
    assert isinstance(exc, CameraDownloadError), exc
    assert str(cam.max_download_bytes) in str(exc)
    assert list(tmp_path.iterdir()) == []  # neither the shot nor its partial file
    assert peak < 8 * MiB  # streamed to disk, never held
    assert rss < 32 * MiB
    time.sleep(0.2)
    assert hostile.sent < cam.max_download_bytes + 16 * MiB
    print(f"\n{mode}: refused after {seconds:.2f} s, {hostile.sent / MiB:.0f} MiB sent by the "
          f"server, Python peak {peak / MiB:.2f} MiB, peak RSS +{rss / MiB:.1f} MiB")


def test_honest_download_still_works(hostile, tmp_path):
    dest = client(hostile.url).download(f"{hostile.url}/files/shot.jpg", tmp_path / "s.jpg")
    assert dest.read_bytes() == b"\xff\xd8 a small shot \xff\xd9"
    assert [p.name for p in tmp_path.iterdir()] == ["s.jpg"]


# --------------------------------------------------------------------------- deadline


@pytest.mark.parametrize("mode", ["trickle-body", "trickle-head"])
def test_trickle_fails_at_the_deadline_not_per_read(hostile, mode):
    hostile.trickle_s = 0.25  # well inside the per-read timeout: it never fires
    cam = client(f"{hostile.url}/{mode}", timeout_s=1.0, request_deadline_s=1.5)
    t0 = time.monotonic()
    with pytest.raises(CameraUnreachable, match=r"within the 1\.5 s deadline"):
        cam.state()
    elapsed = time.monotonic() - t0
    assert 1.4 <= elapsed < 4.5, elapsed  # a loaded CI machine: the bound is the point
    assert hostile.sent >= 3  # bytes did come, each within the per-read timeout


def test_one_byte_a_second_download_fails_at_the_deadline(hostile, tmp_path):
    # 1 byte/s against a 2 s deadline and a 30 s per-read timeout (a download's floor)
    hostile.redirect_to = ""
    cam = client(hostile.url, download_deadline_s=2.0)
    t0 = time.monotonic()
    with pytest.raises(CameraDownloadError, match=r"within the 2 s deadline"):
        cam.download(f"{hostile.url}/trickle-body/x.jpg", tmp_path / "x.jpg")
    elapsed = time.monotonic() - t0
    assert 1.9 <= elapsed < 5.0, elapsed
    assert list(tmp_path.iterdir()) == []
    print(f"\n1 byte/s download: failed after {elapsed:.2f} s (deadline 2 s)")


def test_silent_server_fails_at_the_deadline():
    """A server that accepts and never answers: the deadline, shorter than the per-read
    timeout, ends the request."""
    with socket.socket() as srv:
        srv.bind(("127.0.0.1", 0))
        srv.listen()
        cam = client(f"http://127.0.0.1:{srv.getsockname()[1]}", timeout_s=10.0,
                     request_deadline_s=1.0)
        t0 = time.monotonic()
        with pytest.raises(CameraUnreachable, match="deadline"):
            cam.info()
        assert time.monotonic() - t0 < 2.0


# --------------------------------------------------------------------------- nonsense


def test_deeply_nested_json_is_a_protocol_error(hostile):
    with pytest.raises(CameraProtocolError, match="malformed JSON"):
        client(f"{hostile.url}/nested").info()


def test_garbage_instead_of_http_is_typed(hostile):
    with pytest.raises(CameraUnreachable):
        client(f"{hostile.url}/garbage").info()


def test_malformed_content_length_is_ignored_and_the_cap_still_holds(hostile):
    assert client(f"{hostile.url}/bad-length").state() == {"state": {}}


def test_no_watchdog_threads_are_left_behind(hostile, tmp_path):
    before = threading.active_count()
    cam = client(hostile.url)
    for _ in range(5):
        cam.download(f"{hostile.url}/files/shot.jpg", tmp_path / "s.jpg")
    time.sleep(0.1)
    assert threading.active_count() <= before + 1  # the server's handler thread, at most
