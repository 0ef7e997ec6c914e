"""The simulated camera's OSC API (level 2, as a RICOH THETA Z1 answers) over real HTTP on
127.0.0.1: response shapes checked against the field names of a THETA's recorded answers
(ricohapi/theta-client's test resources, docs/capture-station.md), the spec's error codes with
their HTTP statuses, and the commands a client beyond grassd's own uses (listFiles, delete,
reset)."""

from __future__ import annotations

import base64
import json
import re
import urllib.error
import urllib.request

import numpy as np
import pytest

from grassd.daemon.camera.bracket import SHUTTER_SPEEDS_S
from grassd.daemon.camera.client import OscClient
from grassd.rigs.simulated_camera import (
    ISO_VALUES,
    MAX_DELETE_URLS,
    OPTIONS,
    SimCamera,
)

pytestmark = pytest.mark.timeout(60)

#: Fields of a THETA Z1's listFiles entry, _detail true (theta-client's
#: listFiles/listfiles_image_10.json and listfiles_z1_group_id.json; lat/lng only with GPS,
#: _thumbSize and thumbnail only with maxThumbSize, the group ids only for those shots).
THETA_ENTRY = {"dateTimeZone", "fileUrl", "height", "isProcessed", "name", "previewUrl",
               "_projectionType", "size", "width"}
THETA_ENTRY_OPTIONAL = {"lat", "lng", "_thumbSize", "thumbnail", "_autoBracketGroupId",
                        "_intervalCaptureGroupId", "_compositeShootingGroupId"}
#: "2022:11:14 17:24:38+09:00" (listfiles_image_10.json)
DATE_TIME_ZONE = re.compile(r"^\d{4}:\d\d:\d\d \d\d:\d\d:\d\d[+-]\d\d:\d\d$")


@pytest.fixture
def cam():
    rng = np.random.default_rng(1)
    with SimCamera(rng.uniform(0.05, 2.0, (16, 32, 3)).astype(np.float32),
                   latency_s=0.01) as c:
        yield c


def execute(cam: SimCamera, name: str, params: dict | None = None) -> tuple[int, dict]:
    """(HTTP status, JSON) of one /osc/commands/execute, error statuses included."""
    body = {"name": name} if params is None else {"name": name, "parameters": params}
    return post(cam, "/osc/commands/execute", body)


def post(cam: SimCamera, path: str, body: dict) -> tuple[int, dict]:
    req = urllib.request.Request(cam.url + path, data=json.dumps(body).encode(),
                                 method="POST", headers={"Content-Type": "application/json"})
    try:
        with urllib.request.urlopen(req, timeout=10) as r:
            assert r.headers["Content-Type"] == "application/json; charset=utf-8"
            return r.status, json.loads(r.read())
    except urllib.error.HTTPError as exc:
        with exc:
            return exc.code, json.loads(exc.read())


def refused(answer: tuple[int, dict], code: str, status: int) -> str:
    """Assert ``answer`` is the spec's error object with ``code`` and HTTP ``status``; returns
    its message. Shape: theta-client's */..._error.json ({error: {code, message}, name,
    state})."""
    got_status, out = answer
    assert (got_status, out["state"], out["error"]["code"]) == (status, "error", code), out
    assert set(out) == {"error", "name", "state"} and set(out["error"]) == {"code", "message"}
    return out["error"]["message"]


def take(cam: SimCamera) -> str:
    """Take a picture as an OSC client does (execute, then poll status); returns its fileUrl."""
    status, out = execute(cam, "camera.takePicture")
    # PhotoCapture/takepicture_progress.json: id, name, progress.completion, state
    assert status == 200 and set(out) == {"id", "name", "progress", "state"}
    assert out["state"] == "inProgress" and out["progress"]["completion"] == 0.0
    while out["state"] == "inProgress":
        status, out = post(cam, "/osc/commands/status", {"id": out["id"]})
    # PhotoCapture/takepicture_done.json: name, results.fileUrl, state
    assert out["state"] == "done" and set(out["results"]) == {"fileUrl"}
    assert {"name", "results", "state"} <= set(out) and out["name"] == "camera.takePicture"
    return out["results"]["fileUrl"]


def list_files(cam: SimCamera, **params) -> dict:
    params = {"fileType": "all", "entryCount": 10, "maxThumbSize": 0, **params}
    status, out = execute(cam, "camera.listFiles", params)
    assert status == 200 and out["state"] == "done", out
    assert set(out["results"]) == {"entries", "totalEntries"}
    return out["results"]


def test_info_names_level_2(cam):
    info = OscClient(cam.url).info()
    assert info.api_levels == (2,)


def test_list_files_answers_as_a_theta_z1(cam):
    urls = [take(cam) for _ in range(3)]
    res = list_files(cam)
    assert res["totalEntries"] == 3
    assert [e["fileUrl"] for e in res["entries"]] == urls[::-1]  # newest first
    for e in res["entries"]:
        assert THETA_ENTRY <= set(e) <= THETA_ENTRY | THETA_ENTRY_OPTIONAL, set(e)
        assert DATE_TIME_ZONE.match(e["dateTimeZone"]), e["dateTimeZone"]
        assert (e["width"], e["height"]) == (32, 16) and e["isProcessed"] is True
        assert e["_projectionType"] == "Equirectangular" and "thumbnail" not in e
        with urllib.request.urlopen(e["fileUrl"], timeout=10) as r:
            assert len(r.read()) == e["size"]
    page = list_files(cam, entryCount=1, startPosition=1, maxThumbSize=640)
    assert page["totalEntries"] == 3 and [e["fileUrl"] for e in page["entries"]] == [urls[1]]
    thumb = base64.b64decode(page["entries"][0]["thumbnail"])
    assert thumb[:2] == b"\xff\xd8" and page["entries"][0]["_thumbSize"] == len(thumb)
    brief = list_files(cam, _detail=False)["entries"][0]
    assert set(brief) == {"name", "fileUrl", "size", "dateTime", "isProcessed", "previewUrl"}
    assert list_files(cam, startPosition=5) == {"entries": [], "totalEntries": 3}
    assert list_files(cam, fileType="video") == {"entries": [], "totalEntries": 0}
    assert "maxThumbSize" in refused(execute(cam, "camera.listFiles", {
        "fileType": "all", "entryCount": 3}), "missingParameter", 400)
    refused(execute(cam, "camera.listFiles", {"fileType": "raw", "entryCount": 3,
                                              "maxThumbSize": 0}), "invalidParameterValue", 400)


def test_get_options_answers_every_name_asked_or_refuses_the_unknown_one(cam):
    names = [*OPTIONS, *(n + "Support" for n in OPTIONS)]
    status, out = execute(cam, "camera.getOptions", {"optionNames": names})
    # getOptions/get_options_capture_mode_image.json: name, results.options, state
    assert status == 200 and set(out) == {"name", "results", "state"}
    opts = out["results"]["options"]
    assert sorted(opts) == sorted(names)  # none left out
    assert opts["captureMode"] == "image" and opts["captureModeSupport"] == ["image", "video"]
    assert opts["exposureCompensation"] == 0.0 and 2.0 in opts["exposureCompensationSupport"]
    assert opts["exposureProgramSupport"] == [1, 2, 4, 9]
    assert opts["isoSupport"] == [0, *ISO_VALUES]
    assert opts["shutterSpeedSupport"] == [0, *SHUTTER_SPEEDS_S]
    assert opts["fileFormat"] == {"type": "jpeg", "width": 32, "height": 16}
    assert {f["type"] for f in opts["fileFormatSupport"]} == {"jpeg", "raw+"}
    assert set(opts["_colorTemperatureSupport"]) == {"maxTemperature", "minTemperature",
                                                     "stepSize"}
    message = refused(execute(cam, "camera.getOptions", {
        "optionNames": ["captureMode", "remainingVideoSeconds"]}), "invalidParameterName", 400)
    assert "remainingVideoSeconds" in message
    refused(execute(cam, "camera.getOptions", {}), "missingParameter", 400)


def test_set_options_checks_every_name_and_value_before_setting_any(cam):
    client = OscClient(cam.url, poll_s=0.01)
    client.set_options(captureMode="image", exposureProgram=1, iso=200, shutterSpeed=0.004,
                       whiteBalance="daylight", exposureCompensation=0.0)
    before = client.get_options("iso", "shutterSpeed", "exposureProgram")
    assert before == {"iso": 200, "shutterSpeed": 0.004, "exposureProgram": 1}
    for options, code in (({"iso": 400, "shutterSpeed": 0.0042}, "invalidParameterValue"),
                          ({"iso": 400, "exposureCompensation": 0.5}, "invalidParameterValue"),
                          ({"iso": 400, "captureMode": "interval"}, "invalidParameterValue"),
                          ({"iso": 400, "_colorTemperature": 2550}, "invalidParameterValue"),
                          ({"iso": 400, "whiteBalance": "sunny"}, "invalidParameterValue"),
                          ({"iso": 400, "isoSupport": [100]}, "invalidParameterName"),
                          ({"iso": 400, "_noSuchOption": 1}, "invalidParameterName")):
        refused(execute(cam, "camera.setOptions", {"options": options}), code, 400)
        assert client.get_options("iso", "shutterSpeed", "exposureProgram") == before
    refused(execute(cam, "camera.setOptions", {}), "missingParameter", 400)


def test_exposure_compensation_moves_the_metered_shutter(cam):
    client = OscClient(cam.url, poll_s=0.01)
    shutters = []
    for ev in (0.0, 2.0):
        client.set_options(exposureProgram=2, exposureCompensation=ev)
        shutters.append(client.metadata(client.take_picture()["fileUrl"])["ExposureTime"])
    assert abs(np.log2(shutters[1] / shutters[0]) - 2.0) <= 1 / 3 + 1e-6, shutters


def test_video_mode_refuses_take_picture_until_image_is_set():
    with SimCamera(np.ones((16, 32, 3), np.float32), latency_s=0.01,
                   capture_mode="video") as cam:
        message = refused(execute(cam, "camera.takePicture"), "disabledCommand", 403)
        assert "video" in message and cam.shots_taken == 0
        status, out = execute(cam, "camera.getOptions", {
            "optionNames": ["captureMode", "fileFormat", "fileFormatSupport"]})
        opts = out["results"]["options"]
        # getOptions/get_options_capture_mode_video.json; options/option_file_format_video4k_60f
        assert opts["captureMode"] == "video" and opts["fileFormat"]["type"] == "mp4"
        assert {f["type"] for f in opts["fileFormatSupport"]} == {"mp4"}
        refused(execute(cam, "camera.setOptions", {"options": {"fileFormat": {
            "type": "jpeg", "width": 32, "height": 16}}}), "invalidParameterValue", 400)
        client = OscClient(cam.url, poll_s=0.01)
        client.set_options(captureMode="image")
        assert client.get_options("fileFormat")["fileFormat"]["type"] == "jpeg"
        assert take(cam).endswith("/files/R0000001.JPG")
        client.set_options(captureMode="video")  # each mode keeps its own format
        assert client.get_options("fileFormat")["fileFormat"]["type"] == "mp4"
        execute(cam, "camera.reset")
        assert client.get_options("captureMode") == {"captureMode": "video"}


def test_reset_restores_the_default_options(cam):
    client = OscClient(cam.url, poll_s=0.01)
    defaults = client.get_options(*OPTIONS)
    client.set_options(exposureProgram=1, iso=800, shutterSpeed=0.01, whiteBalance="shade",
                       captureMode="video")
    assert client.get_options(*OPTIONS) != defaults
    status, out = execute(cam, "camera.reset")
    assert (status, out) == (200, {"name": "camera.reset", "state": "done"})
    assert client.get_options(*OPTIONS) == defaults


def test_delete_removes_the_named_files_or_none(cam):
    urls = [take(cam) for _ in range(3)]
    message = refused(execute(cam, "camera.delete", {
        "fileUrls": [urls[0], cam.url + "/files/R9999999.JPG"]}), "invalidParameterValue", 400)
    assert "R9999999.JPG" in message and list_files(cam)["totalEntries"] == 3
    status, out = execute(cam, "camera.delete", {"fileUrls": [urls[0]]})
    # delete/delete_done.json: name and state only
    assert (status, out) == (200, {"name": "camera.delete", "state": "done"})
    assert [e["fileUrl"] for e in list_files(cam)["entries"]] == urls[:0:-1]
    with pytest.raises(urllib.error.HTTPError) as gone:
        urllib.request.urlopen(urls[0], timeout=10)
    assert gone.value.code == 404
    refused(execute(cam, "camera.delete", {"fileUrls": ["all", urls[1]]}),
            "invalidParameterValue", 400)
    refused(execute(cam, "camera.delete", {"fileUrls": [urls[1]] * (MAX_DELETE_URLS + 1)}),
            "tooManyParameters", 403)
    refused(execute(cam, "camera.delete", {}), "missingParameter", 400)
    assert execute(cam, "camera.delete", {"fileUrls": ["video"]})[0] == 200  # no videos
    assert list_files(cam)["totalEntries"] == 2
    assert execute(cam, "camera.delete", {"fileUrls": ["all"]})[0] == 200
    assert list_files(cam) == {"entries": [], "totalEntries": 0} and not cam.files


def test_a_command_it_does_not_have_is_unknown_command(cam):
    for name in ("camera.startSession", "camera.startCapture", "camera.nothing"):
        assert name in refused(execute(cam, name, {}), "unknownCommand", 400)


def test_a_sensor_view_reaches_the_dng_as_its_raw_and_profile(tmp_path):
    """A scene source that returns a SensorView: the JPEG and the meter read its radiance, the
    DNG holds its raw response (every channel in its own proportion) and its profile."""
    rawpy = pytest.importorskip("rawpy")
    from grassd.calib.colour_spaces import M_REC709_TO_XYZ
    from grassd.rigs.simulated_camera import SensorView

    radiance = np.full((16, 32, 3), 0.5, np.float32)
    raw = np.broadcast_to(np.array([0.2, 0.4, 0.1], np.float32), radiance.shape)
    profile = np.array([[0.9, 0.1, 0.0], [0.2, 1.0, -0.1], [0.0, 0.1, 0.8]])
    with SimCamera(radiance, latency_s=0.01, read_noise=0.0, full_well=1e12,
                   scene_source=lambda: SensorView(radiance, raw, profile)) as cam:
        assert execute(cam, "camera.setOptions", {"options": {"fileFormat": {
            "type": "raw+", "width": 32, "height": 16}}})[0] == 200
        status, out = execute(cam, "camera.takePicture")
        while out["state"] == "inProgress":
            status, out = post(cam, "/osc/commands/status", {"id": out["id"]})
        assert out["state"] == "done", out
        with urllib.request.urlopen(out["results"]["_dngFileUrl"], timeout=10) as r:
            (tmp_path / "shot.dng").write_bytes(r.read())
    with rawpy.imread(str(tmp_path / "shot.dng")) as dng:
        img = dng.raw_image_visible.astype(float) - np.array(dng.black_level_per_channel)[
            dng.raw_colors_visible]
        means = [img[dng.raw_colors_visible == c].mean() for c in range(4)]
        rgb_cam = np.array(dng.color_matrix)[:, :3]  # LibRaw's, from the DNG's ColorMatrix1
    rgb = np.array([means[0], (means[1] + means[3]) / 2, means[2]])
    np.testing.assert_allclose(rgb / rgb[1], raw[0, 0] / raw[0, 0, 1], rtol=0.01)
    cam_rgb = profile @ M_REC709_TO_XYZ
    np.testing.assert_allclose(rgb_cam, np.linalg.inv(cam_rgb / cam_rgb.sum(1, keepdims=True)),
                               atol=2e-3)
