"""Bad camera and sensor behaviour: each is a clear typed error, retried with backoff, and no
bundle (not even a partial one) is left in the inbox. The camera is a real HTTP server on
127.0.0.1, the lux sensor a real pymodbus server."""

from __future__ import annotations

import dataclasses
import os
import socket
import threading
import time
import tomllib

import numpy as np
import pytest

from grassd.daemon.camera.config import CaptureConfig
from grassd.daemon.capture.station import Station
from grassd.daemon.core.config.settings import load_default_config
from grassd.daemon.core.errors import (
    BracketUnusable,
    CameraBusy,
    CameraCommandTimeout,
    CameraDownloadError,
    CameraHttpError,
    CameraProtocolError,
    CameraUnreachable,
    ExposureMissing,
    LuxSensorSilent,
)
from grassd.daemon.core.store.manifest import parse_manifest
from grassd.rigs.simulated_camera import SimCamera
from grassd.rigs.simulated_site import SimLuxSensor


def small_env() -> np.ndarray:
    """A 64 x 32 sky: smooth gradient plus a bright compact sun."""
    h, w = 32, 64
    v = np.linspace(1.0, 0.2, h)[:, None, None] * np.ones((h, w, 3))
    v[5:7, 20:22] = 3000.0
    return v.astype(np.float32)


@pytest.fixture
def camera():
    with SimCamera(small_env(), scene_scale=1000.0, latency_s=0.01) as cam:
        yield cam


def station(tmp_path, url: str, **kw) -> Station:
    cfg = CaptureConfig(camera=url, shots=5, retries=kw.pop("retries", 1), retry_s=0.01,
                        timeout_s=2.0, command_timeout_s=kw.pop("command_timeout_s", 2.0), **kw)
    st = Station(cfg, tmp_path / "inbox", tmp_path / "state", kw.get("modbus"))
    st.client.poll_s = 0.01
    (tmp_path / "inbox").mkdir(exist_ok=True)
    return st


def inbox_entries(tmp_path) -> list[str]:
    return sorted(p.name for p in (tmp_path / "inbox").iterdir())


def test_good_capture_writes_one_complete_bundle(tmp_path, camera):
    out = station(tmp_path, camera.url).capture(lux=8000.0)
    assert inbox_entries(tmp_path) == [out.bundle.name]
    data = tomllib.loads((out.bundle / "manifest.toml").read_text())
    m = parse_manifest(data, out.bundle)  # the daemon's own parser accepts it
    assert m.light.ambient_lux == 8000.0 and m.light.hdri.exists()
    assert data["capture"]["camera_model"] == "grassd SimCam Z1"
    assert len(data["capture"]["exposures_s"]) == 5
    assert m.light.sun_from_hdri == data["capture"]["sun_clipped"]


FAULTS = [
    ({"http_status": 503}, CameraHttpError),
    ({"http_status": 404}, CameraHttpError),
    ({"malformed_json": True}, CameraProtocolError),
    ({"never_finish": True}, CameraCommandTimeout),
    ({"truncated_download": True}, CameraDownloadError),
    ({"missing_exposure": True}, ExposureMissing),
    ({"file_url_base": "file://"}, CameraProtocolError),  # file:///files/R0000001.JPG
]


@pytest.mark.parametrize(("fault", "error"), FAULTS, ids=[next(iter(f)) for f, _ in FAULTS])
def test_camera_fault_is_typed_retried_and_leaves_no_bundle(tmp_path, camera, fault, error,
                                                            caplog):
    for k, v in fault.items():
        setattr(camera.faults, k, v)
    st = station(tmp_path, camera.url, command_timeout_s=0.3)
    with pytest.raises(error) as exc:
        st.capture(lux=5000.0)
    assert str(exc.value)  # one line that says what happened
    assert "attempt 1 of 2" in caplog.text  # retried once, with backoff
    assert inbox_entries(tmp_path) == []


def test_fault_that_clears_is_retried_into_a_bundle(tmp_path, camera):
    camera.faults.http_status, camera.faults.times = 503, 2
    out = station(tmp_path, camera.url, retries=3).capture(lux=5000.0)
    assert inbox_entries(tmp_path) == [out.bundle.name]


def test_a_file_url_naming_another_host_is_fetched_from_the_camera(tmp_path, camera):
    """A THETA in client mode names its files by its own IP, while the configuration may
    name it otherwise: the shots are fetched from the configured camera, never from the host
    a fileUrl names (203.0.113.9 is TEST-NET-3: nothing answers there)."""
    camera.faults.file_url_base = "http://203.0.113.9:9"
    out = station(tmp_path, camera.url).capture(lux=5000.0)
    assert inbox_entries(tmp_path) == [out.bundle.name]
    assert len(tomllib.loads((out.bundle / "manifest.toml").read_text())
               ["capture"]["exposures_s"]) == 5


def test_a_second_capture_into_the_same_state_directory_is_refused_while_one_runs(tmp_path):
    """`grassd capture` while the daemon captures (one state directory, one camera) would
    shoot between the other's exposures and remove its work files as leftovers: it fails at
    once with CameraBusy naming the holder, and the running capture completes."""
    with SimCamera(small_env(), scene_scale=1000.0, latency_s=0.05) as cam:
        first, second = station(tmp_path, cam.url), station(tmp_path, cam.url)
        result: dict = {}
        t = threading.Thread(target=lambda: result.update(out=first.capture(lux=5000.0)))
        t.start()
        lock_file = tmp_path / "state" / "capture" / "camera.lock"
        deadline = time.monotonic() + 10.0
        while not (lock_file.exists() and lock_file.read_text()) and time.monotonic() < deadline:
            time.sleep(0.005)
        with pytest.raises(CameraBusy, match=rf"PID {os.getpid()}\)"):
            second.capture(lux=5000.0)
        t.join(30.0)
        assert inbox_entries(tmp_path) == [result["out"].bundle.name]
        assert lock_file.read_text() == ""  # released: the next capture may run
        n_first = cam.shots_taken
        again = second.capture(lux=5000.0)
        assert cam.shots_taken - n_first == n_first  # the refused one took no shot
    assert inbox_entries(tmp_path) == sorted([result["out"].bundle.name, again.bundle.name])


def test_camera_unreachable(tmp_path):
    with socket.socket() as s:  # a port nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    with pytest.raises(CameraUnreachable, match="unreachable"):
        station(tmp_path, f"http://127.0.0.1:{port}").capture(lux=5000.0)
    assert inbox_entries(tmp_path) == []


@pytest.mark.parametrize(("scale", "word"), [(1e9, "clipped"), (1e-9, "black")])
def test_bracket_all_clipped_or_all_black(tmp_path, camera, scale, word):
    camera.set_scene(scene_scale=scale)
    st = station(tmp_path, camera.url, shutter_s=0.001)  # a fixed bracket: no meter to save it
    with pytest.raises(BracketUnusable, match=word):
        st.capture(lux=5000.0)
    assert inbox_entries(tmp_path) == []


def test_silent_lux_sensor(tmp_path, camera):
    modbus = load_default_config().light.modbus
    with SimLuxSensor(modbus, lux=12000.0) as sensor:
        cfg = dataclasses.replace(sensor.config, timeout_s=0.2, retries=0)
        st = station(tmp_path, camera.url)
        st.modbus = cfg
        sensor.silent = True
        with pytest.raises(LuxSensorSilent):
            st.capture()
        assert inbox_entries(tmp_path) == []
        sensor.silent = False
        out = st.capture()  # the same station reads it once it answers again
        assert out.manifest["ambient_lux"] == pytest.approx(12000.0)


def test_digest_auth_as_a_theta_in_client_mode(tmp_path):
    with SimCamera(small_env(), username="THETAYN10010104", password="10010104",
                   latency_s=0.01) as cam:
        bad = station(tmp_path, cam.url, username="THETAYN10010104", password="wrong",
                      retries=0)
        with pytest.raises(CameraHttpError, match="401"):
            bad.capture(lux=5000.0)
        good = station(tmp_path, cam.url, username="THETAYN10010104", password="10010104")
        assert good.capture(lux=5000.0).bundle.exists()


def test_two_sensors_split_ambient_and_sun(tmp_path, camera):
    modbus = load_default_config().light.modbus
    with SimLuxSensor(modbus, lux=50000.0) as sun_side, \
            SimLuxSensor(dataclasses.replace(modbus, unit=2), lux=15000.0) as shaded:
        st = station(tmp_path, camera.url, shaded_unit=2, shaded_port=shaded.port)
        st.modbus = dataclasses.replace(sun_side.config, timeout_s=0.5)
        out = st.capture()
    assert out.manifest["ambient_lux"] == pytest.approx(15000.0)
    assert out.manifest["sun_lux"] == pytest.approx(35000.0)


def test_sensor_difference_with_the_sun_below_the_horizon_is_no_sun(tmp_path, camera):
    """At a site where it is night now, what the two sensors differ by is their mismatch: the
    bundle records sun_lux 0 (ingest would refuse sun lux from below the horizon); where the
    sun is up, the difference stands."""
    from datetime import UTC, datetime

    from grassd.sim.sun import sun_position

    now = datetime.now(UTC)
    sites = [(0.0, float(lon)) for lon in range(-180, 180, 15)]
    night = min(sites, key=lambda s: sun_position(*s, now)[1])
    day = max(sites, key=lambda s: sun_position(*s, now)[1])
    modbus = load_default_config().light.modbus
    with SimLuxSensor(modbus, lux=1500.0) as unshaded, \
            SimLuxSensor(dataclasses.replace(modbus, unit=2), lux=1000.0) as shaded:
        got = {}
        for name, site in (("night", night), ("day", day)):
            (tmp_path / name).mkdir()
            st = station(tmp_path / name, camera.url, shaded_unit=2, shaded_port=shaded.port)
            st.modbus = dataclasses.replace(unshaded.config, timeout_s=0.5)
            st.site = site
            got[name] = st.capture().manifest["sun_lux"]
    assert got == {"night": 0.0, "day": pytest.approx(500.0)}


def test_raw_plus_capture_merges_the_dngs(tmp_path, camera):
    out = station(tmp_path, camera.url, file_format="raw+").capture(lux=5000.0)
    c = out.manifest["capture"]
    assert c["merge_method"] == "linear" and c["response"] == "linear RAW (rawpy)"
    assert c["file_format"] == "raw+"
    assert inbox_entries(tmp_path) == [out.bundle.name]


def test_a_partial_bundle_left_by_a_crash_is_removed(tmp_path, camera):
    (tmp_path / "inbox").mkdir()
    leftover = tmp_path / "inbox" / ".capture-20260101T000000000Z.partial"
    leftover.mkdir()
    (leftover / "sky.exr").write_bytes(b"half")
    out = station(tmp_path, camera.url).capture(lux=5000.0)
    assert inbox_entries(tmp_path) == [out.bundle.name]


def test_aperture_is_set_and_recorded(tmp_path, camera):
    out = station(tmp_path, camera.url, aperture=3.5).capture(lux=5000.0)
    assert camera.f_number == 3.5 and out.manifest["capture"]["f_number"] == 3.5
    with pytest.raises(CameraHttpError, match="aperture"):  # not one of the lens' f-numbers
        station(tmp_path, camera.url, aperture=4.0, retries=0).capture(lux=5000.0)
