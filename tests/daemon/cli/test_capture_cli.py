"""`grassd camera sim` and `grassd capture` as a user runs them (real processes, real HTTP on
127.0.0.1), and the [capture] config section."""

from __future__ import annotations

import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from grassd.daemon.core.config.settings import default_config_text, parse_config
from grassd.daemon.core.errors import ConfigError
from grassd.rigs.processes import end_process
from grassd.sim.hdri import default_site_hdri

GRASSD = str(Path(sys.executable).parent / "grassd")


@pytest.fixture(scope="module")
def sim_camera():
    proc = subprocess.Popen([GRASSD, "camera", "sim", "--hdri", str(default_site_hdri()), "--width",
                             "128", "--curve", "soft"], stdout=subprocess.PIPE, text=True)
    url = proc.stdout.readline().strip()  # the first line is the URL
    assert url.startswith("http://127.0.0.1:")
    yield url
    end_process(proc, 10)


def test_capture_cli_writes_a_bundle_then_reuses_the_response(sim_camera, tmp_path):
    args = [GRASSD, "capture", "--camera", sim_camera, "--inbox", str(tmp_path / "inbox"),
            "--lux", "7000", "--state-dir", str(tmp_path / "state")]
    first = subprocess.run(args, capture_output=True, text=True, timeout=120)
    assert first.returncode == 0, first.stderr
    assert "recovered from this bracket" in first.stdout
    second = subprocess.run(args, capture_output=True, text=True, timeout=120)
    assert second.returncode == 0, second.stderr
    assert "cached" in second.stdout  # the response of this camera is cached per camera
    bundles = sorted((tmp_path / "inbox").iterdir())
    assert len(bundles) == 2 and not [b for b in bundles if b.name.startswith(".")]
    m = tomllib.loads((bundles[0] / "manifest.toml").read_text())
    assert m["ambient_lux"] == 7000.0 and m["capture"]["lux_source"] == "--lux"
    assert list((tmp_path / "state" / "capture" / "response").glob("*.json"))


def test_capture_cli_unreachable_camera_is_one_line_exit_2(tmp_path):
    r = subprocess.run([GRASSD, "capture", "--camera", "http://127.0.0.1:9", "--inbox",
                        str(tmp_path / "inbox"), "--lux", "7000", "--retries", "0",
                        "--state-dir", str(tmp_path / "state")],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 2
    assert r.stderr.strip().splitlines()[-1].startswith("grassd: error: camera ")
    assert "unreachable" in r.stderr
    assert list((tmp_path / "inbox").iterdir()) == []


def test_capture_section_parses_and_names_bad_keys():
    cfg = parse_config(default_config_text() + '\n[capture]\ncamera = "http://10.0.0.5"\n'
                       'shots = 7\nfile_format = "raw+"\n')
    assert cfg.capture is not None and cfg.capture.shots == 7
    assert cfg.capture.file_format == "raw+" and cfg.capture.shutter_s == 0.0  # 0: metered
    assert parse_config(default_config_text()).capture is None
    for bad, key in (('camera = "http://x"\nshots = 1', "capture.shots"),
                     ('camera = "192.168.1.1"', "capture.camera"),
                     ('camera = "http://x"\nbracket = 3', "capture.bracket")):
        with pytest.raises(ConfigError) as exc:
            parse_config(default_config_text() + f"\n[capture]\n{bad}\n")
        assert key in str(exc.value) and exc.value.line is not None
