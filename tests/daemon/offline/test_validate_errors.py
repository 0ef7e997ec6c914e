"""Bad capture directories give one clear, typed error each, and the CLI prints it as one line
with exit code 2. The captures are real DNGs from the virtual camera and a real EXR."""

from __future__ import annotations

import logging
import os
import tomllib

import numpy as np
import pytest
import tomli_w
from click.testing import CliRunner

from grassd.calib.charts import get_chart
from grassd.calib.checker_photo import checker_scene
from grassd.calib.errors import CornersOutsideImageError
from grassd.calib.virtual_camera import VirtualCamera
from grassd.daemon.cli.main import main
from grassd.daemon.offline.validate import (
    CaptureManifest,
    CaptureManifestError,
    LengthOrderError,
    MissingPhotoError,
    MixedCamerasError,
    Photo,
    Series,
    load_manifest,
    manifest_to_toml,
    measure_real,
)
from grassd.sim.hdri import write_exr
from grassd.sim.light_input import LightInput

QUAD = ((10.0, 12.0), (54.0, 12.0), (56.0, 50.0), (8.0, 50.0))


def _capture(tmp_path, *, lengths=(0.0, 5.0, 10.0, 20.0), camera=None, odd_one=None):
    """A small capture: checker + flat photos getting greener with length (no rendering)."""
    cam = camera or VirtualCamera()
    write_exr(tmp_path / "env.exr", np.full((16, 32, 3), 0.5, np.float32))
    white = np.full(3, 50.0)
    img, corners = checker_scene(get_chart("spydercheckr-24"), white)
    cam.photograph(tmp_path / "checker.dng", img, white)
    photos = []
    for i, x in enumerate(lengths):
        frac = x / 20.0
        colour = (1 - frac) * np.array([0.5, 0.45, 0.1]) + frac * np.array([0.05, 0.2, 0.03])
        which = odd_one if (odd_one is not None and i == 2) else cam
        path = which.photograph(tmp_path / f"p{i}.dng", np.ones((64, 64, 3)) * colour * white,
                                white)
        photos.append(Photo(path, x, QUAD))
    m = CaptureManifest(root=tmp_path, light=LightInput(tmp_path / "env.exr", 500.0),
                        checker_photo=tmp_path / "checker.dng",
                        checker_corners=tuple(map(tuple, corners.tolist())),
                        series=(Series((170.0, 2.0, 0.0), tuple(photos), True),))
    (tmp_path / "capture.toml").write_text(manifest_to_toml(m))
    return m


def _cli_error(path) -> str:
    res = CliRunner().invoke(main, ["validate", str(path), "-q"])
    assert res.exit_code == 2, res.output
    lines = [ln for ln in res.output.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("grassd: error: "), res.output
    return lines[0]


def test_good_capture_loads_and_measures(tmp_path):
    _capture(tmp_path)
    m = load_manifest(tmp_path)
    assert [p.length_mm for p in m.series[0].photos] == [0.0, 5.0, 10.0, 20.0]
    real = measure_real(m)
    assert real.camera["model"] == "Virtual Camera"
    # the photos get greener with length: OGCD grows monotonically from 0
    assert real.ogcd[0][0] == 0.0 and np.all(np.diff(real.ogcd[0]) > 0)
    assert real.checker_rgb.shape == (24, 3)


def test_missing_photo(tmp_path):
    _capture(tmp_path)
    (tmp_path / "p2.dng").unlink()
    with pytest.raises(MissingPhotoError, match="p2.dng does not exist"):
        load_manifest(tmp_path)
    assert "p2.dng does not exist" in _cli_error(tmp_path)


def _edited(text: str, change) -> str:
    """capture.toml ``text`` with ``change`` (a function of its parsed table) applied."""
    data = tomllib.loads(text)
    change(data)
    return tomli_w.dumps(data)


def test_corners_outside_the_image(tmp_path):
    _capture(tmp_path)
    good = (tmp_path / "capture.toml").read_text()

    def third_corner_out(d):
        d["series"][0]["photos"][0]["corners"][2] = [156.0, 50.0]

    def checker_corner_out(d):
        d["checker_corners"][0][1] = -35.84

    (tmp_path / "capture.toml").write_text(_edited(good, third_corner_out))
    with pytest.raises(CornersOutsideImageError, match=r"outside p0.dng \(64 x 64"):
        measure_real(load_manifest(tmp_path))
    assert "[[156.0, 50.0]]" in _cli_error(tmp_path)
    # the checker's corners are checked against the checker photo
    (tmp_path / "capture.toml").write_text(_edited(good, checker_corner_out))
    with pytest.raises(CornersOutsideImageError, match=r"checker corner.*outside checker.dng"):
        measure_real(load_manifest(tmp_path))


def test_lengths_not_increasing(tmp_path):
    _capture(tmp_path, lengths=(0.0, 10.0, 5.0, 20.0))
    with pytest.raises(LengthOrderError, match="strictly increasing.*5 mm after 10 mm"):
        load_manifest(tmp_path)
    assert "strictly increasing" in _cli_error(tmp_path)


def test_mixed_cameras(tmp_path):
    other = VirtualCamera(model="Other Camera", cfa_pattern="BGGR", bits=12)
    _capture(tmp_path, odd_one=other)
    with pytest.raises(MixedCamerasError, match="p2.dng was taken with grassd Other Camera"):
        measure_real(load_manifest(tmp_path))
    assert "same camera" in _cli_error(tmp_path)


def test_malformed_manifests(tmp_path):
    _capture(tmp_path)
    good = (tmp_path / "capture.toml").read_text()
    assert good.startswith('hdri = "env.exr"\nambient_lux = 500.0\n')  # a bundle's names
    top = 'hdri = "env.exr"\n'
    cases = {
        "checker_chart = [": "not valid TOML",
        good.replace(top, top + "colour = 3\n"): r"capture\.toml:2: colour: unknown key",
        good.replace("ambient_lux = 500.0", "ambient_lux = \"bright\""):
            r"capture\.toml:2: ambient_lux: must be a finite number",
        # checked as a bundle's manifest is: lux range, sun direction, file type, pairs
        good.replace("ambient_lux = 500.0", "ambient_lux = -5.0"):
            r"ambient_lux: -5 lux is impossible",
        good.replace(top, top + "sun_lux = 30000.0\nsun_azimuth_deg = 400.0\n"
                     "sun_elevation_deg = 40.0\n"): r":3: sun_azimuth_deg: must be between 0.0",
        good.replace(top, top + "sun_lux = 30000.0\nsun_azimuth_deg = 180.0\n"):
            "give both sun_azimuth_deg and sun_elevation_deg, or neither",
        good.replace(top, top + "sun_lux = 40000.0\nsun_azimuth_deg = 180.0\n"
                     "sun_elevation_deg = -5.0\n"): r"sun_lux: impossible sun: .*horizon",
        good.replace('hdri = "env.exr"', 'hdri = "env.png"'): r"hdri: 'env.png' must be an "
                                                              r"OpenEXR \(.exr\) or Radiance",
        good.replace('checker_raw = "checker.dng"\n', ""): r"checker_raw: required key",
        _edited(good, lambda d: d["series"][0].update(viewpoint=[170.0, 2.0])): "viewpoint",
    }
    for text, message in cases.items():
        (tmp_path / "capture.toml").write_text(text)
        with pytest.raises(CaptureManifestError, match=message):
            load_manifest(tmp_path)
    (tmp_path / "capture.toml").unlink()
    with pytest.raises(CaptureManifestError, match="needs a capture.toml"):
        load_manifest(tmp_path)
    assert "capture.toml" in _cli_error(tmp_path)


def _old_names(text: str) -> str:
    """``text`` (written now) as capture.toml was written before it took a bundle manifest's
    names: ``chart``, ``[light] hdri, lux``, ``[checker] photo, corners``."""
    d = tomllib.loads(text)
    return tomli_w.dumps({
        "chart": d.pop("checker_chart"),
        "light": {"hdri": d.pop("hdri"), "lux": d.pop("ambient_lux")},
        "checker": {"photo": d.pop("checker_raw"), "corners": d.pop("checker_corners")}, **d})


def test_old_names_are_read_with_a_warning(tmp_path, caplog):
    """A capture directory written before the vocabulary was the bundle's still loads, to the
    same manifest, with one warning that names each rename; its mistakes name the old keys."""
    _capture(tmp_path)
    new = load_manifest(tmp_path)
    assert not caplog.records
    old = _old_names((tmp_path / "capture.toml").read_text())
    (tmp_path / "capture.toml").write_text(old)
    with caplog.at_level(logging.WARNING, logger="grassd.daemon.offline.validate"):
        assert load_manifest(tmp_path) == new
    [warning] = caplog.records
    assert warning.levelno == logging.WARNING
    for rename in ("chart -> checker_chart", "light.hdri -> hdri", "light.lux -> ambient_lux",
                   "checker.photo -> checker_raw", "checker.corners -> checker_corners"):
        assert rename in warning.getMessage()
    assert "deprecated" in warning.getMessage()
    cases = {
        old.replace("[light]", "[light]\ncolour = 3"): r"light\.colour: unknown key",
        old.replace("lux = 500.0", "lux = \"bright\""): r"capture\.toml:\d+: light\.lux: must",
        old.replace("lux = 500.0", "lux = -5.0"): r"light\.lux: -5 lux is impossible",
        old.replace("[light]", "ambient_lux = 400.0\n[light]"):
            r"ambient_lux: given twice: also as light\.lux",
        old.replace("[light]", "sun_azimuth_deg = 180.0\n[light]"):
            r"capture\.toml: give both sun_azimuth_deg",
    }
    for text, message in cases.items():
        (tmp_path / "capture.toml").write_text(text)
        with pytest.raises(CaptureManifestError, match=message):
            load_manifest(tmp_path)


@pytest.mark.parametrize("args", [["validate", "CAP", "-q", "--samples", "64"],
                                  ["experiment", "paper", "--quick", "-q", "--out", "OUT"]])
def test_one_replicate_is_refused_before_any_work(tmp_path, args):
    """RenderSettings accepts replicates=1 (an adaptive run's top-up batch), but a run needs
    two for its standard errors: `--replicates 1` must be refused naming the option, not fail
    after tracing with an internal "2 independent batches" message (or write NaN errors)."""
    _capture(tmp_path)
    args = [str(tmp_path) if a == "CAP" else str(tmp_path / "out") if a == "OUT" else a
            for a in args]
    res = CliRunner().invoke(main, [*args, "--replicates", "1"])
    assert res.exit_code == 2, res.output
    assert "--replicates" in res.output and "1" in res.output, res.output
    assert not (tmp_path / "out").exists()


def test_hostile_manifests_are_refused_with_a_bundles_caps(tmp_path):
    """capture.toml is read as a bundle's manifest is: nested 5000 deep (arrays, or tables
    named by dotted keys), over the manifest byte cap, or a FIFO, it is one clear error line
    from ``grassd validate`` (no RecursionError traceback, no hang)."""
    from grassd.daemon.core.config.limits import DEFAULT_LIMITS
    from grassd.daemon.core.store.manifest import MAX_MANIFEST_DEPTH

    _capture(tmp_path)
    good = (tmp_path / "capture.toml").read_text()
    path = tmp_path / "capture.toml"
    deep = f"more than {MAX_MANIFEST_DEPTH} deep"
    cases = {
        good + "x = " + "[" * 5000 + "]" * 5000 + "\n": deep,
        good + "[" + ".".join(["t"] * 5000) + "]\nv = 1\n": deep,
        good + "#" * DEFAULT_LIMITS.manifest_bytes + "\n": "over the cap",
    }
    for text, word in cases.items():
        path.write_text(text)
        with pytest.raises(CaptureManifestError, match=word):
            load_manifest(tmp_path)
        line = _cli_error(tmp_path)
        assert word in line and "capture.toml" in line and "Traceback" not in line, line
    path.unlink()
    os.mkfifo(path)  # a reader that opened it blocking would wait for a writer forever
    line = _cli_error(tmp_path)
    assert "FIFO" in line, line
