"""grassd's OSC client puts the camera in still-image capture (``captureMode`` "image") before a
bracket: a simulated camera left in video mode, as a THETA someone filmed with, still gives a
bracket; one that will not leave video mode gives a typed error quoting its answer. Real HTTP on
127.0.0.1."""

from __future__ import annotations

import time

import numpy as np
import pytest

from grassd.daemon.camera.bracket import BracketPlan, capture_bracket
from grassd.daemon.camera.client import OscClient
from grassd.daemon.core.errors import CameraCommandRefused, CameraHttpError, CaptureModeRefused
from grassd.rigs.simulated_camera import SimCamera

pytestmark = pytest.mark.timeout(60)

PLAN = BracketPlan(shots=3, ev_step=2.0)


def video_camera(mode_switch_s: float = 0.0) -> SimCamera:
    rng = np.random.default_rng(2)
    return SimCamera(rng.uniform(0.05, 2.0, (16, 32, 3)).astype(np.float32), latency_s=0.01,
                     capture_mode="video", mode_switch_s=mode_switch_s)


def test_a_camera_left_in_video_mode_refuses_a_picture_until_told():
    """What the bracket below must overcome: in video mode a picture is refused, typed."""
    with video_camera() as cam:
        with pytest.raises(CameraCommandRefused) as exc:
            OscClient(cam.url, poll_s=0.01).take_picture()
        assert (exc.value.code, exc.value.status) == ("disabledCommand", 403)
        assert exc.value.command == "camera.takePicture" and cam.shots_taken == 0
        assert "disabledCommand" in str(exc.value) and exc.value.detail in str(exc.value)


def test_the_bracket_from_a_camera_left_in_video_mode_succeeds(tmp_path):
    with video_camera() as cam:
        shots = capture_bracket(OscClient(cam.url, poll_s=0.01), PLAN, tmp_path)
        assert cam.capture_mode.value == "image"  # the client set it
        assert len(shots) == 3 and all(s.path.exists() for s in shots)
        assert cam.shots_taken == 4  # the metering shot and the bracket


def test_a_camera_slow_to_switch_modes_is_waited_for(tmp_path):
    with video_camera(mode_switch_s=0.5) as cam:
        client = OscClient(cam.url, poll_s=0.02)
        start = time.monotonic()
        client.ensure_image_mode()
        assert time.monotonic() - start >= 0.5 and cam.capture_mode.value == "image"
        assert len(capture_bracket(client, PLAN, tmp_path)) == 3


def test_a_camera_that_never_reports_image_mode_is_a_typed_error(tmp_path):
    with video_camera(mode_switch_s=60.0) as cam:
        client = OscClient(cam.url, poll_s=0.02, command_timeout_s=0.3)
        with pytest.raises(CaptureModeRefused) as exc:
            capture_bracket(client, PLAN, tmp_path)
        assert "still reports 'video' after 0.3 s" in str(exc.value)
        assert "stop any video" in str(exc.value) and cam.shots_taken == 0


def test_a_camera_already_in_image_mode_is_not_switched(tmp_path):
    with video_camera() as cam:
        client = OscClient(cam.url, poll_s=0.01)
        client.set_options(captureMode="image")
        cam.faults.mode_locked = True  # a setOptions of captureMode would now be refused
        assert len(capture_bracket(client, PLAN, tmp_path)) == 3


def test_a_camera_that_will_not_leave_video_mode_says_what_it_answered(tmp_path):
    with video_camera() as cam:
        cam.faults.mode_locked = True  # as while it records a video
        with pytest.raises(CaptureModeRefused) as exc:
            capture_bracket(OscClient(cam.url, poll_s=0.01), PLAN, tmp_path)
        err = exc.value
        assert (err.command, err.code, err.status) == ("camera.setOptions", "disabledCommand",
                                                       403)
        assert "while the camera records" in err.detail
        message = str(err)
        assert "disabledCommand" in message and err.detail in message
        assert "captureMode 'image'" in message and "stop any video" in message
        assert isinstance(err, CameraHttpError)  # the station retries it as any HTTP refusal
        assert cam.shots_taken == 0 and cam.capture_mode.value == "video"
