"""The OSC client tier: a third-party Open Spherical Camera client nobody here wrote,
``osc-client`` 2.0.3 (npm, MIT, BublTechnology), drives ``grassd camera sim`` (a real process on
127.0.0.1) through info, state, setOptions captureMode, getOptions, takePicture polled to done,
listFiles and delete, starting from video mode as a THETA someone filmed with.

The package is installed once into a cache beside the venv (``OSC_CLIENT_DIR``, or
``GRASSD_TEST_OSC_CLIENT_DIR``); without node and npm, or without the npm registry, the tier is
skipped with one line saying what it needs.
``.ci/run`` installs Debian's ``nodejs`` and ``npm``."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from grassd.rigs.processes import end_process
from grassd.sim.hdri import default_site_hdri

GRASSD = str(Path(sys.executable).parent / "grassd")
#: The client and the version tested.
PACKAGE, VERSION = "osc-client", "2.0.3"
#: Where it is installed (kept between runs: a rerun needs no registry).
OSC_CLIENT_DIR = Path(os.environ.get("GRASSD_TEST_OSC_CLIENT_DIR") or Path(sys.prefix) / "share"
                      / "grassd-tests" / f"{PACKAGE}-{VERSION}")
DRIVER = Path(__file__).with_name("osc_client_drive.js")
#: The one line a machine without node or npm skips the tier with.
NEEDS_NODE = "the OSC client tier needs node and npm on PATH (apt-get install nodejs npm)"

pytestmark = pytest.mark.timeout(300)


def installed(prefix: Path) -> bool:
    """The package at its version is in ``prefix``'s node_modules."""
    meta = prefix / "node_modules" / PACKAGE / "package.json"
    try:
        return json.loads(meta.read_text())["version"] == VERSION
    except (OSError, ValueError, KeyError):
        return False


def osc_client_modules() -> Path:
    """The node_modules directory holding the package, installed into :data:`OSC_CLIENT_DIR`
    with npm on first use; skips the test (one line) without node/npm or the registry."""
    if not (shutil.which("node") and shutil.which("npm")):
        pytest.skip(NEEDS_NODE)
    if not installed(OSC_CLIENT_DIR):
        OSC_CLIENT_DIR.mkdir(parents=True, exist_ok=True)
        r = subprocess.run(["npm", "install", "--prefix", str(OSC_CLIENT_DIR), "--no-audit",
                            "--no-fund", "--cache", str(OSC_CLIENT_DIR / ".npm-cache"),
                            f"{PACKAGE}@{VERSION}"], capture_output=True, text=True,
                           timeout=240)
        if r.returncode != 0 or not installed(OSC_CLIENT_DIR):
            lines = r.stderr.strip().splitlines() or ["no output"]
            why = next((ln for ln in lines if ln.startswith("npm error code ")), lines[-1])[:160]
            pytest.skip(f"the OSC client tier could not install {PACKAGE}@{VERSION} with npm "
                        f"({why}): it needs the npm registry (registry.npmjs.org) once")
    return OSC_CLIENT_DIR / "node_modules"


def test_a_third_party_osc_client_drives_the_simulated_camera():
    modules = osc_client_modules()
    proc = subprocess.Popen([GRASSD, "camera", "sim", "--hdri", str(default_site_hdri()),
                             "--width", "64", "--capture-mode", "video"],
                            stdout=subprocess.PIPE, text=True)
    try:
        url = proc.stdout.readline().strip()
        assert url.startswith("http://127.0.0.1:"), url
        host, port = url.removeprefix("http://").split(":")
        r = subprocess.run(["node", str(DRIVER), host, port], capture_output=True, text=True,
                           timeout=120, env={**os.environ, "NODE_PATH": str(modules)})
    finally:
        end_process(proc, 10)
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout)
    assert out["info"]["apiLevel"] == [2] and out["state"]["state"]["_captureStatus"] == "idle"
    assert out["pictureBefore"]["code"] == "disabledCommand"  # started in video mode
    assert out["setOptions"] == {"name": "camera.setOptions", "state": "done"}
    opts = out["getOptions"]["results"]["options"]
    assert opts == {"captureMode": "image", "exposureCompensation": 0.0, "iso": 0,
                    "captureModeSupport": ["image", "video"]}
    assert out["unknownOption"]["code"] == "invalidParameterName"
    shot = out["takePicture"]  # the answer of /osc/commands/status: it polled
    assert shot["state"] == "done" and shot["id"] and shot["results"]["fileUrl"].startswith(url)
    listed = out["listFiles"]["results"]
    assert listed["totalEntries"] == 1
    assert [e["fileUrl"] for e in listed["entries"]] == [shot["results"]["fileUrl"]]
    assert out["delete"] == {"name": "camera.delete", "state": "done"}
    assert out["listFilesAfter"]["results"] == {"entries": [], "totalEntries": 0}
    assert out["unknownCommand"]["code"] == "unknownCommand"


def skip_line(env: dict[str, str]) -> str:
    """The one SKIPPED line of the tier run in a pytest of its own with ``env``."""
    test = f"{Path(__file__)}::test_a_third_party_osc_client_drives_the_simulated_camera"
    r = subprocess.run([sys.executable, "-m", "pytest", "-q", "-rs", "-p", "no:cacheprovider",
                        test], capture_output=True, text=True, timeout=120,
                       env={**os.environ, **env}, cwd=Path(__file__).parents[3])
    assert r.returncode == 0, r.stdout + r.stderr
    skipped = [line for line in r.stdout.splitlines() if line.startswith("SKIPPED")]
    assert len(skipped) == 1, r.stdout
    return skipped[0]


def test_without_node_the_tier_skips_with_one_line_saying_what_to_install(tmp_path):
    """A PATH without node or npm: really missing."""
    bare = tmp_path / "bin"
    bare.mkdir()
    assert not shutil.which("node", path=str(bare))
    assert skip_line({"PATH": str(bare)}).endswith(NEEDS_NODE)


def test_without_the_registry_the_tier_skips_with_one_line(tmp_path):
    """npm with a registry nobody listens on (port 9 on 127.0.0.1) and an empty cache."""
    if not (shutil.which("node") and shutil.which("npm")):
        pytest.skip(NEEDS_NODE)
    line = skip_line({"GRASSD_TEST_OSC_CLIENT_DIR": str(tmp_path / "modules"),
                      "npm_config_registry": "http://127.0.0.1:9/",
                      "npm_config_fetch_retries": "0"})
    assert f"could not install {PACKAGE}@{VERSION}" in line and "ECONNREFUSED" in line, line
    assert "registry.npmjs.org" in line
