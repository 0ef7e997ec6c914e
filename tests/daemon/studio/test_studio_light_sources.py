"""Where ``grassd studio`` takes its light from, and what it refuses at start: an ``--hdri``
that cannot be loaded and a ``--state-dir`` that does not exist stop it with a click error
(exit 2) before it prints its URL; an empty state directory lights it with the embedded default
site and says so; archived bundles whose panorama is missing or unreadable are left out, with a
warning, and the newest usable one is the current light."""

from __future__ import annotations

import logging
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import start_studio, stop_studio

from grassd.sim.hdri import default_site_hdri, write_exr

SITE = default_site_hdri()


def grassd_studio(tmp: Path, *args: str) -> subprocess.CompletedProcess:
    """``grassd studio --port 0 ARGS`` run in ``tmp`` to its end (it ends only when refused)."""
    return subprocess.run([sys.executable, "-m", "grassd.daemon.cli", "studio", "--port", "0",
                           *args], capture_output=True, text=True, timeout=120, cwd=tmp)


def _truncated(path: Path) -> str:
    path.write_bytes(SITE.read_bytes()[:4000])
    return "corrupt or truncated OpenEXR"


def _text(path: Path) -> str:
    path.write_text("not a panorama\n")
    return "neither OpenEXR nor Radiance"


def _png(path: Path) -> str:
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(64))
    return "neither OpenEXR nor Radiance"


def _nan(path: Path) -> str:
    img = np.ones((64, 128, 3), np.float32)
    img[3, 5, 1] = np.nan
    write_exr(path, img)
    return "hold NaN or infinity"


@pytest.mark.parametrize("make", [_truncated, _text, _png, _nan], ids=lambda f: f.__name__[1:])
def test_an_hdri_that_cannot_be_loaded_refuses_to_start(make, tmp_path):
    reason = make(tmp_path / "sky.exr")
    res = grassd_studio(tmp_path, "--hdri", "sky.exr")
    assert res.returncode == 2, res.stderr
    assert "grassd studio: http" not in res.stdout  # refused before it served
    assert "Invalid value for '--hdri': cannot use sky.exr as the light: sky.exr" in res.stderr
    assert reason in res.stderr and "Traceback" not in res.stderr


def test_a_state_dir_that_does_not_exist_is_refused(tmp_path):
    res = grassd_studio(tmp_path, "--hdri", str(SITE), "--state-dir", "typo/state")
    assert res.returncode == 2, res.stderr
    assert "grassd studio: http" not in res.stdout
    assert ("Invalid value for '--state-dir': typo/state: no such directory; give the daemon's "
            "state directory") in res.stderr
    assert not (tmp_path / "typo").exists()  # nor its cache made


def test_an_empty_state_dir_lights_the_studio_with_the_default_site_and_says_so(tmp_path):
    state = tmp_path / "state"
    state.mkdir()
    studio = start_studio(tmp_path, "--state-dir", str(state))
    try:
        status, body = studio.request("api/state")
        assert status == 200
        assert [s["name"] for s in body["lights"]] == ["default-site"]
    finally:
        stop_studio(studio)
    said = [ln for ln in studio.log.read_text().splitlines() if "archived bundle" in ln]
    assert said == [f"grassd studio: {state} holds no usable archived bundle; the light is "
                    "the embedded default site"]


# ------------------------------------------------------------------------ archived bundles


def _bundle(archive: Path, name: str, age_s: float, hdri: Path | None = None,
            hdri_bytes: bytes | None = None) -> Path:
    """An archived bundle ``name`` (manifest naming sky.exr) whose directory is ``age_s`` old:
    sky.exr a copy of ``hdri``, else ``hdri_bytes``, else absent."""
    d = archive / name
    d.mkdir(parents=True)
    (d / "manifest.toml").write_text('timestamp = 2025-06-01T12:00:00+02:00\nhdri = "sky.exr"\n'
                                     "ambient_lux = 1000.0\n")
    if hdri is not None:
        shutil.copy(hdri, d / "sky.exr")
    elif hdri_bytes is not None:
        (d / "sky.exr").write_bytes(hdri_bytes)
    t = 1.7e9 - age_s
    os.utime(d, (t, t))
    return d


def test_broken_bundles_are_left_out_and_the_newest_usable_one_is_current(tmp_path, caplog):
    from grassd.daemon.core.config.settings import resolve_config
    from grassd.daemon.studio.lights import Lights, archived_sources

    archive = tmp_path / "archive"
    _bundle(archive, "old-missing", 600)
    _bundle(archive, "old-truncated", 500, hdri_bytes=SITE.read_bytes()[:4000])
    _bundle(archive, "old-good", 400, SITE)
    _bundle(archive, "good", 300, SITE)
    _bundle(archive, "missing", 200)
    _bundle(archive, "truncated", 100, hdri_bytes=SITE.read_bytes()[:4000])
    _bundle(archive, "text", 50, hdri_bytes=b"not a panorama\n")
    (archive / "no-manifest").mkdir()  # not a bundle: passed over without a word
    cfg = resolve_config(None, tmp_path)
    with caplog.at_level(logging.WARNING, "grassd.daemon.studio.lights"):
        sources = archived_sources(tmp_path, cfg)
    # behind the first usable one only the file is looked for (said when chosen, if broken)
    assert [s.name for s in sources] == ["bundle:good", "bundle:old-good",
                                         "bundle:old-truncated"]
    assert [s.label for s in sources] == ["current: good", "old-good", "old-truncated"]
    assert Lights(sources).default == "bundle:good"
    left_out = {r.getMessage().split(":", 1)[0]: r.getMessage() for r in caplog.records}
    assert set(left_out) == {"archived bundle missing left out", "archived bundle truncated "
                             "left out", "archived bundle text left out",
                             "archived bundle old-missing left out"}
    assert ("cannot use old-missing/sky.exr as the light: its file is missing"
            in left_out["archived bundle old-missing left out"])
    assert ("cannot use missing/sky.exr as the light: HDRI file missing/sky.exr does not exist"
            in left_out["archived bundle missing left out"])
    assert "truncated/sky.exr: corrupt or truncated OpenEXR" in \
        left_out["archived bundle truncated left out"]
    assert "text/sky.exr: neither OpenEXR nor Radiance" in \
        left_out["archived bundle text left out"]
    assert all(s.image is None for s in sources)  # checked, not kept (the simulator reads it)


def test_a_state_dir_of_broken_bundles_only_has_no_sources(tmp_path, caplog):
    from grassd.daemon.core.config.settings import resolve_config
    from grassd.daemon.studio.lights import archived_sources

    _bundle(tmp_path / "archive", "missing", 10)
    with caplog.at_level(logging.WARNING, "grassd.daemon.studio.lights"):
        assert archived_sources(tmp_path, resolve_config(None, tmp_path)) == []
    assert len(caplog.records) == 1 and "missing/sky.exr" in caplog.records[0].getMessage()
