"""A chart CSV named by a relative ``checker_chart`` in capture.toml is the capture
directory's, as every other file of a capture is, whatever the working directory."""

from __future__ import annotations

import tomllib
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import tomli_w

from grassd.calib.charts import get_chart
from grassd.calib.checker_photo import checker_scene
from grassd.calib.virtual_camera import VirtualCamera
from grassd.daemon.offline.validate import (
    CaptureManifest,
    MissingPhotoError,
    Photo,
    Series,
    load_manifest,
    manifest_to_toml,
    measure_real,
)
from grassd.sim.hdri import write_exr
from grassd.sim.light_input import LightInput

QUAD = ((10.0, 12.0), (54.0, 12.0), (56.0, 50.0), (8.0, 50.0))


def _write_chart(path: Path, lab: np.ndarray, names: tuple[str, ...]) -> None:
    path.write_text("name,L,a,b\n" + "".join(f"{n},{v[0]:.4f},{v[1]:.4f},{v[2]:.4f}\n"
                                             for n, v in zip(names, lab, strict=True)))


def _capture(root: Path, chart_name: str) -> None:
    """A capture of flat photos (no rendering) whose capture.toml names ``chart_name``."""
    cam = VirtualCamera()
    write_exr(root / "env.exr", np.full((16, 32, 3), 0.5, np.float32))
    white = np.full(3, 50.0)
    img, corners = checker_scene(get_chart("spydercheckr-24"), white)
    cam.photograph(root / "checker.dng", img, white)
    photos = []
    for i, x in enumerate((0.0, 10.0, 20.0)):
        colour = (1 - x / 20) * np.array([0.5, 0.45, 0.1]) + x / 20 * np.array([0.05, 0.2, 0.03])
        photos.append(Photo(cam.photograph(root / f"p{i}.dng",
                                           np.ones((64, 64, 3)) * colour * white, white), x, QUAD))
    m = CaptureManifest(root=root, light=LightInput(root / "env.exr", 500.0),
                        checker_photo=root / "checker.dng",
                        checker_corners=tuple(map(tuple, corners.tolist())),
                        series=(Series((170.0, 2.0, 0.0), tuple(photos), True),))
    data = tomllib.loads(manifest_to_toml(m))
    data["checker_chart"] = chart_name
    (root / "capture.toml").write_text(tomli_w.dumps(data))


def test_a_relative_chart_csv_is_read_from_the_capture_directory(tmp_path, monkeypatch):
    spyder = get_chart("spydercheckr-24")
    capture = tmp_path / "capture"
    (capture / "charts").mkdir(parents=True)
    _write_chart(capture / "charts" / "mine.csv", spyder.lab, spyder.patch_names)
    elsewhere = tmp_path / "elsewhere"
    (elsewhere / "charts").mkdir(parents=True)
    # the working directory holds another chart of the same name: it must not be the one read
    decoy = spyder.lab + np.array([0.0, 6.0, -6.0])
    _write_chart(elsewhere / "charts" / "mine.csv", decoy, spyder.patch_names)
    _capture(capture, "charts/mine.csv")
    monkeypatch.chdir(elsewhere)

    m = load_manifest(capture)
    assert Path(m.chart) == capture / "charts" / "mine.csv"
    assert np.allclose(get_chart(m.chart).lab, spyder.lab, atol=1e-4)
    real = measure_real(m)
    reference = measure_real(replace(m, chart="spydercheckr-24"))
    assert np.allclose(real.checker_rgb, reference.checker_rgb)
    assert np.allclose(real.ogcd[0], reference.ogcd[0])
    # written back relative to the capture, as the photos are
    assert tomllib.loads(manifest_to_toml(m))["checker_chart"] == "charts/mine.csv"

    monkeypatch.chdir(capture)  # from the capture directory itself: the same file
    assert Path(load_manifest(".").chart).resolve() == (capture / "charts" / "mine.csv")


def test_a_missing_chart_csv_names_the_key_and_the_capture_directory(tmp_path, monkeypatch):
    capture = tmp_path / "capture"
    capture.mkdir()
    _capture(capture, "gone.csv")
    monkeypatch.chdir(tmp_path)
    (tmp_path / "gone.csv").write_text("# in the working directory only\n")
    with pytest.raises(MissingPhotoError, match=r"checker_chart .*capture/gone\.csv does not"):
        load_manifest(capture)


def test_built_in_chart_names_stay_names(tmp_path):
    _capture(tmp_path, "ColorChecker Classic")
    assert load_manifest(tmp_path).chart == "ColorChecker Classic"
