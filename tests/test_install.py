"""A real install: ``make install DESTDIR=...`` and every ``grassd``
command from that plain install.

One module fixture runs ``make install DESTDIR=<tmp>/root``: it builds the wheel once from a
clean copy of this checkout and ``pip install``s it, without extras, into a fresh venv
(``<tmp>/root/opt/grassd``; dependencies from the package index or pip's cache), then installs
the unit, the sysusers.d, tmpfiles.d and udev files, the ``/usr/bin/grassd`` link and
``/etc/grassd/grassd.toml``. The tests read that tree, verify the installed unit with
``systemd-analyze``, and run a cheap real path of each command with the installed venv's Python
(``python -I``: nothing of this checkout or its .venv on the path; the venv's scripts name their
final paths, ``/opt/grassd/bin/python``, which a staging tree does not have). The last test
uninstalls and checks that the configuration stays. The tier is skipped, in one line, where no
venv can be made or the package index cannot be reached.
"""

from __future__ import annotations

import importlib.util
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
import tomllib
import urllib.request
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest
from daemon_harness import display_2x2
from PIL import Image

from grassd.rigs.processes import end_process

pytestmark = pytest.mark.long

ROOT = Path(__file__).resolve().parents[1]
OPT = "/opt/grassd"
CACHE = os.environ.get("GRASSD_CACHE_DIR", str(ROOT / ".venv" / "grassd-cache"))
#: the commands `grassd --help` lists, each with the test that runs it
COMMANDS = {
    "bundles": "test_daemon_on_simulated_hardware",
    "calibrate": "test_daemon_on_simulated_hardware",
    "camera": "test_camera_sim_and_capture_raw_plus",
    "capture": "test_camera_sim_and_capture_raw_plus",
    "check-config": "test_installed_check_config",
    "controllers": "test_controllers",
    "demo": "test_demo_example_curve",
    "experiment": "test_experiment_virtual_capture, test_experiment_paper",
    "fit": "test_fit",
    "history": "test_daemon_on_simulated_hardware",
    "measure": "test_measure_refuses_a_camera_never_set_up",
    "run": "test_daemon_on_simulated_hardware",
    "show": "test_daemon_on_simulated_hardware",
    "simulate": "test_simulate_and_export_scene",
    "status": "test_daemon_on_simulated_hardware",
    "studio": "test_studio",
    "sweep": "test_sweep",
    "validate": "test_validate",
}
#: packages of the test extra that a plain install must not have
TEST_ONLY = ("pytest", "hypothesis", "mitsuba", "ruff", "mkdocs")


def _env() -> dict[str, str]:
    """The environment of the installed commands: no virtualenv of this checkout on PATH."""
    venv_bin = str(ROOT / ".venv" / "bin")
    env = {k: v for k, v in os.environ.items()
           if k not in ("VIRTUAL_ENV", "PYTHONPATH", "PYTHONHOME", "MAKEFLAGS", "MFLAGS",
                        "MAKELEVEL", "NOTIFY_SOCKET", "STATE_DIRECTORY", "RUNTIME_DIRECTORY")}
    env["PATH"] = os.pathsep.join(p for p in env.get("PATH", "").split(os.pathsep)
                                  if p != venv_bin)
    env["GRASSD_CACHE_DIR"] = CACHE  # Taichi's kernel cache, shared with the other tests
    env["PYTHONUNBUFFERED"] = "1"
    return env


@dataclass
class Install:
    destdir: Path
    work: Path

    @property
    def venv(self) -> Path:
        return self.destdir / OPT.lstrip("/")

    @property
    def python(self) -> Path:
        return self.venv / "bin" / "python"

    @property
    def config(self) -> Path:
        return self.destdir / "etc" / "grassd" / "grassd.toml"

    def site_packages(self) -> Path:
        (sp,) = self.venv.glob("lib/python3*/site-packages")
        return sp

    def site_hdri(self) -> Path:
        """The embedded default site HDRI, as the installed package holds it."""
        return self.site_packages() / "grassd" / "sim" / "data" / "default_site.exr"

    def argv(self, *args: str | Path) -> list[str]:
        return [str(self.python), "-I", str(self.venv / "bin" / "grassd"), *map(str, args)]

    def grassd(self, *args: str | Path, rc: int | None = 0,
               timeout: float = 300) -> subprocess.CompletedProcess:
        """Run the installed ``grassd ARGS`` in the work directory; check its exit status."""
        r = subprocess.run(self.argv(*args), capture_output=True, text=True, timeout=timeout,
                           cwd=self.work, env=_env(), stdin=subprocess.DEVNULL)
        if rc is not None:
            assert r.returncode == rc, (f"grassd {' '.join(map(str, args))}: exit "
                                        f"{r.returncode}\n{r.stdout[-3000:]}\n{r.stderr[-3000:]}")
        return r

    def popen(self, *args: str | Path, log: Path) -> subprocess.Popen:
        """Start the installed ``grassd ARGS``: stdout piped (its first line is read), stderr
        to ``log``."""
        return subprocess.Popen(self.argv(*args), stdout=subprocess.PIPE, text=True,
                                stderr=log.open("wb"), cwd=self.work, env=_env(),
                                stdin=subprocess.DEVNULL)


def _make(*args: str, timeout: float = 1200) -> subprocess.CompletedProcess:
    return subprocess.run(["make", "--no-print-directory", "-C", str(ROOT), *args,
                           f"PYTHON={sys.executable}"], capture_output=True, text=True,
                          timeout=timeout, env=_env())


def _cannot_install() -> str | None:
    """Why this machine cannot make a venv with grassd's dependencies, or None."""
    if shutil.which("make") is None:
        return "make is not installed"
    if importlib.util.find_spec("ensurepip") is None:
        return "Python's venv cannot install pip here (Debian: apt-get install python3-venv)"
    with tempfile.TemporaryDirectory() as tmp:  # one small dependency, from the index
        probe = subprocess.run([sys.executable, "-m", "pip", "download", "--quiet", "--no-deps",
                                "--no-cache-dir", "--retries", "1", "--timeout", "20",
                                "--dest", tmp, "tomli-w>=1.2"],
                               capture_output=True, text=True, timeout=300)
    if probe.returncode != 0:
        last = (probe.stderr.strip().splitlines() or ["?"])[-1]
        return f"the package index cannot be reached ({last[:120]})"
    return None


@pytest.fixture(scope="module")
def installed(tmp_path_factory) -> Iterator[Install]:
    """``make install DESTDIR=...`` once: the wheel built and installed (no extras) once."""
    reason = _cannot_install()
    if reason:
        pytest.skip(f"install tier skipped: {reason}")
    tmp = tmp_path_factory.mktemp("install")
    dest = tmp / "root"
    t0 = time.monotonic()
    # PYCOMPILE=no: byte-compiling the whole venv (~7000 files) would double the time; the
    # commands below compile what they import, as any Python does
    r = _make("install", f"DESTDIR={dest}", "PYCOMPILE=no")
    seconds = time.monotonic() - t0
    assert r.returncode == 0, f"make install failed:\n{r.stdout[-4000:]}\n{r.stderr[-4000:]}"
    print(f"make install DESTDIR=... (wheel built once, installed once): {seconds:.0f} s")
    (tmp / "work").mkdir()
    yield Install(dest, tmp / "work")


# ----------------------------------------------------------------------------- the tree
def test_installed_tree(installed):
    d = installed.destdir
    for path, mode in (("usr/lib/systemd/system/grassd.service", 0o644),
                       ("usr/lib/sysusers.d/grassd.conf", 0o644),
                       ("usr/lib/tmpfiles.d/grassd.conf", 0o644),
                       ("usr/lib/udev/rules.d/60-grassd-serial.rules", 0o644),
                       ("etc/grassd/grassd.toml", 0o640)):
        assert (d / path).is_file(), path
        assert (d / path).stat().st_mode & 0o777 == mode, path
    assert (d / "etc/grassd").stat().st_mode & 0o777 == 0o750
    assert (d / "usr/lib/sysusers.d/grassd.conf").read_text() == \
        (ROOT / "systemd/grassd.sysusers.conf").read_text()
    # the unit's ExecStart is the link, and the link is the venv's script
    unit = (d / "usr/lib/systemd/system/grassd.service").read_text()
    assert "ExecStart=/usr/bin/grassd run --config /etc/grassd/grassd.toml" in unit
    link = d / "usr/bin/grassd"
    assert os.readlink(link) == f"{OPT}/bin/grassd"
    script = installed.venv / "bin" / "grassd"
    assert os.access(script, os.X_OK)
    # the venv names its final paths, never the staging tree
    shebang = script.read_text().splitlines()[0]
    assert re.fullmatch(rf"#!{OPT}/bin/python[0-9.]*", shebang), shebang
    assert (d / shebang[3:]).exists()  # the interpreter, once the tree is in place
    assert f"{OPT}.new" not in (installed.venv / "pyvenv.cfg").read_text()
    for f in (installed.venv / "bin").iterdir():
        if f.is_file() and not f.is_symlink():
            assert str(d) not in f.read_text(errors="replace"), f
    # the configuration is the package's default
    default = installed.site_packages() / "grassd" / "daemon" / "core" / "config" / "default.toml"
    assert installed.config.read_text() == default.read_text() == \
        (ROOT / "daemon/core/config/default.toml").read_text()


def test_plain_install_has_no_extras_and_carries_the_license(installed):
    r = subprocess.run([str(installed.python), "-I", "-c",
                        "import importlib.metadata as m, json; print(json.dumps("
                        "{d.metadata['Name'].lower(): d.version for d in m.distributions()}))"],
                       capture_output=True, text=True, check=True, env=_env())
    dists = json.loads(r.stdout)
    assert "grassd" in dists and "tifffile" in dists
    assert not [p for p in TEST_ONLY if p in dists], sorted(dists)
    (info,) = installed.site_packages().glob("grassd-*.dist-info")
    assert (info / "licenses" / "LICENSE").read_text() == (ROOT / "LICENSE").read_text()
    assert "License-Expression: MIT" in (info / "METADATA").read_text()
    assert "MIT License" in (ROOT / "LICENSE").read_text()


def _systemd_analyze_unusable(tmp: Path) -> str | None:
    if shutil.which("systemd-analyze") is None:
        return "systemd-analyze is not installed (Debian: apt-get install systemd)"
    probe = tmp / "probe.service"
    probe.write_text("[Service]\nExecStart=/bin/true\n")
    r = subprocess.run(["systemd-analyze", "verify", str(probe)], capture_output=True,
                       text=True, cwd=tmp)
    if r.returncode != 0:
        return f"systemd-analyze cannot run here: {(r.stderr.strip() or '?').splitlines()[0]}"
    return None


def test_installed_unit_verifies(installed, tmp_path):
    """``systemd-analyze verify`` on the installed unit; verify insists that ExecStart exists,
    so the copy it reads runs the staged venv's script the link points to (nothing else
    changes)."""
    reason = _systemd_analyze_unusable(tmp_path)
    if reason:
        pytest.skip(reason)
    unit = (installed.destdir / "usr/lib/systemd/system/grassd.service").read_text()
    target = installed.destdir / os.readlink(installed.destdir / "usr/bin/grassd").lstrip("/")
    copy = tmp_path / "grassd.service"
    copy.write_text(unit.replace("ExecStart=/usr/bin/grassd ", f"ExecStart={target} "))
    r = subprocess.run(["systemd-analyze", "verify", str(copy)], capture_output=True,
                       text=True, cwd=tmp_path)
    assert (r.returncode, r.stdout, r.stderr) == (0, "", "")


def test_installed_check_config(installed):
    r = installed.grassd("check-config", "--config", installed.config)
    assert f"{installed.config}: OK" in r.stdout
    assert "controller /dev/serial/by-id/usb-grassd_controller_0-if00" in r.stdout


def test_install_never_overwrites_the_config(installed):
    """``make install-data`` (``make install`` without the venv) keeps a changed config."""
    text = installed.config.read_text().replace("rows = 4", "rows = 2", 1)
    assert text != installed.config.read_text()
    installed.config.write_text(text)
    r = _make("install-data", f"DESTDIR={installed.destdir}")
    assert r.returncode == 0, r.stdout + r.stderr
    assert "kept the existing /etc/grassd/grassd.toml" in r.stdout
    assert installed.config.read_text() == text


# ------------------------------------------------------------------ every command, plainly
def test_help_lists_the_commands_tested_here(installed):
    out = installed.grassd("--help").stdout
    listed = re.findall(r"^  ([a-z][a-z-]+)  ", out.split("Commands:", 1)[1], re.M)
    assert sorted(listed) == sorted(COMMANDS), \
        "a command without a smoke path here (or one gone): update COMMANDS and add its test"
    assert installed.grassd("--version").stdout.strip().endswith("0.1.0")


def test_demo_example_curve(installed):
    out = installed.grassd("demo", "--example-curve").stdout
    assert "level" in out.lower()


def test_simulate_and_export_scene(installed):
    w, hdri = installed.work, installed.site_hdri()
    installed.grassd("simulate", "--hdri", hdri, "--lux", "5000", "--view", "170,2,0",
                     "--lengths", "0,20", "--samples", "16", "--replicates", "2",
                     "--json", w / "sim.json")
    sim = json.loads((w / "sim.json").read_text())
    assert sim
    installed.grassd("simulate", "export-scene", "--hdri", hdri, "--lux", "5000",
                     "--length", "10", "--view", "170,2,0", "--out", w / "scene")
    assert (w / "scene" / "scene.json").is_file()


@pytest.fixture(scope="module")
def virtual_capture(installed) -> Path:
    """``grassd experiment virtual-capture`` (DNGs written by tifffile): 2 viewpoints x 3
    lengths at 32 px, 1 sample per pixel (LibRaw opens nothing much smaller)."""
    out = installed.work / "capture"
    installed.grassd("experiment", "virtual-capture", out, "--hdri", installed.site_hdri(),
                     "--lux", "5000", "--view", "170,2,0", "--view", "160,2,30",
                     "--lengths", "0,10,20", "--width", "32", "--spp", "1")
    return out


def test_experiment_virtual_capture(virtual_capture):
    assert len(list(virtual_capture.glob("*.dng"))) == 7  # 2 x 3 lengths + the checker
    assert (virtual_capture / "capture.toml").is_file()


def test_validate(installed, virtual_capture):
    installed.grassd("validate", virtual_capture, "--samples", "16", "--replicates", "2", "-q",
                     "--json", installed.work / "validate.json")
    assert json.loads((installed.work / "validate.json").read_text())["viewpoints"]


def test_fit(installed, virtual_capture):
    installed.grassd("fit", virtual_capture, "--params", "splay_deg", "--samples", "16",
                     "--layouts", "2", "-q", "--json", installed.work / "fit.json")
    assert "splay_deg" in (installed.work / "fit.json").read_text()


def test_measure_refuses_a_camera_never_set_up(installed):
    """The installed ``grassd measure --now`` loads the measurement (renderer included) and,
    with a camera never set up, fails with its report and the fix (the whole measurement runs
    in tests/daemon/measure)."""
    cfg = installed.work / "measure.toml"
    state = installed.work / "measure-state"
    default = ROOT / "daemon" / "core" / "config" / "default.toml"
    cfg.write_text(f'state_dir = "{state}"\ncontrol_socket = "{state}/control.sock"\n'
                   + default.read_text() + '\n[measure]\ncamera = "http://127.0.0.1:9"\n')
    r = installed.grassd("measure", "--now", "--config", cfg, rc=2)
    assert "grassd measure setup" in r.stderr, r.stderr
    assert len(list((state / "measure").glob("*T*Z.json"))) == 1


def test_experiment_paper(installed):
    """No HDRI ships for the paper's environments: without --hdri-dir, one clear error; with a
    folder holding Env 1's panorama (here the default site's), a tiny run."""
    r = installed.grassd("experiment", "paper", "--quick", rc=2)
    assert "Missing option '--hdri-dir'" in r.stderr
    hdri_dir = installed.work / "hdri"
    hdri_dir.mkdir()
    shutil.copy(installed.site_hdri(), hdri_dir / "studio.exr")
    out = installed.work / "paper"
    installed.grassd("experiment", "paper", "--quick", "--env", "Env 1", "--hdri-dir", hdri_dir,
                     "--out", out, "--samples", "16", "--replicates", "2", "--trials", "1",
                     "-q")
    assert (out / "report.json").is_file() and (out / "report.html").is_file()


def test_sweep(installed):
    out = installed.work / "sweep"
    installed.grassd("sweep", "--hdri", installed.site_hdri(), "--lux", "5000", "--view",
                     "170,2,0", "--lengths", "0:20:10", "--samples", "16", "--replicates", "2",
                     "--workers", "1", "--out", out)
    assert (out / "sweep.sqlite").is_file()


def _config(installed: Install, extra: str = "") -> Path:
    """A small configuration: a 2 x 2 display on two controllers, one viewpoint, cheap
    simulation settings (``run --simulate-hardware`` replaces the ports and the sensor)."""
    path = installed.work / "grassd.toml"
    path.write_text(display_2x2(f'state_dir = "state"\ncache_dir = "{CACHE}"\n'
                                '[site]\nlatitude = 48.1\nlongitude = 11.6\n'
                                'timezone = "Europe/Berlin"\n',
                                samples=64, seed=2, replicates=2, extra=extra))
    return path


def _stop(proc: subprocess.Popen) -> int:
    return end_process(proc, 60)


def test_camera_sim_and_capture_raw_plus(installed):
    """``grassd camera sim`` serves JPEG + DNG shots (the DNGs written by tifffile);
    ``grassd capture`` with ``file_format = "raw+"`` merges them into a bundle in the inbox,
    which the daemon test below calibrates from."""
    cam = installed.popen("camera", "sim", "--hdri", installed.site_hdri(), "--width", "128",
                          log=installed.work / "camera.log")
    try:
        url = cam.stdout.readline().strip()
        assert url.startswith("http://127.0.0.1:"), (installed.work / "camera.log").read_text()
        cfg = _config(installed, f'[capture]\ncamera = "{url}"\nfile_format = "raw+"\n'
                                 "shots = 5\nretries = 0\n")
        r = installed.grassd("capture", "--config", cfg, "--lux", "5000")
    finally:
        _stop(cam)
    (bundle,) = (installed.work / "state" / "inbox").iterdir()
    manifest = tomllib.loads((bundle / "manifest.toml").read_text())
    assert manifest["ambient_lux"] == 5000.0
    assert "RAW" in manifest["capture"]["response"], (r.stdout, manifest["capture"])


def test_daemon_on_simulated_hardware(installed):
    """``grassd run --simulate-hardware`` calibrates from the captured bundle and pushes the
    table; ``status``, ``history``, ``bundles list``, ``show`` (content on, no receivers) and
    ``calibrate --now`` against it."""
    cfg = _config(installed, "[content]\nenabled = true\n[content.sacn]\nenabled = false\n"
                             "[content.artnet]\nenabled = false\n")
    state = installed.work / "state"
    if not (state / "inbox").is_dir() or not any((state / "inbox").iterdir()):
        pytest.skip("no bundle: test_camera_sim_and_capture_raw_plus did not run first")
    log = installed.work / "daemon.log"
    proc = installed.popen("run", "--simulate-hardware", "--config", cfg, "--tick", "0.2",
                           log=log)
    try:
        deadline = time.monotonic() + 300
        while True:
            assert proc.poll() is None, log.read_text()[-4000:]
            assert time.monotonic() < deadline, log.read_text()[-4000:]
            r = installed.grassd("status", "--config", cfg, "--json", rc=None)
            st = json.loads(r.stdout) if r.returncode == 0 else {}
            if st.get("running") and st.get("health") == "ok" and st.get("runs"):
                break
            time.sleep(1)
        assert st["runs"][0]["status"] == "ok" and st["runs"][0]["trigger"] == "bundle"
        assert all(c["in_sync"] for c in st["controllers"]) and len(st["controllers"]) == 2
        assert "#1" in installed.grassd("history", "--config", cfg).stdout
        assert "no quarantined bundles" in installed.grassd("bundles", "list", "--config",
                                                             cfg).stdout
        picture = installed.work / "green.png"
        Image.new("RGB", (4, 4), (20, 160, 40)).save(picture)
        shown = installed.grassd("show", str(picture), "--duration", "30", "--config", cfg)
        assert "the daemon shows green.png" in shown.stdout, shown.stdout
        st = json.loads(installed.grassd("status", "--config", cfg, "--json").stdout)
        assert st["content"]["source"] == "script", st["content"]
        installed.grassd("calibrate", "--now", "--wait", "--config", cfg, "--timeout", "240",
                         timeout=300)
        st = json.loads(installed.grassd("status", "--config", cfg, "--json").stdout)
        assert st["run_counts"]["ok"] == 2, st["runs"]
    finally:
        rc = _stop(proc)
    assert rc == 0, log.read_text()[-4000:]


def test_controllers(installed):
    """``controllers sim`` on a pty; ``scan``, ``push`` and ``status`` against it."""
    cfg = _config(installed)
    state = installed.work / "ctl-state"
    sim = installed.popen("controllers", "sim", "--count", "2", "--pixels", "4", "--duration",
                          "120", "--state-dir", installed.work / "ctl",
                          log=installed.work / "controllers.log")
    try:
        first = sim.stdout.readline()
        port = first.split(" -> ")[0].strip()
        assert Path(port).exists(), first
        common = ("--port", port, "--config", cfg, "--state-dir", state)
        out = installed.grassd("controllers", "scan", *common, "-a", "1-2").stdout
        assert re.findall(r"^address (\d+): uid", out, re.M) == ["1", "2"], out
        table = installed.work / "table.json"
        table.write_text(json.dumps({"lengths_um": [i * 78 for i in range(256)],
                                     "table_id": 7}))
        out = installed.grassd("controllers", "push", *common, "--table", table, "-a",
                               "1-2").stdout
        assert out.count("table 0x00000007") == 2 and out.count("active") == 2, out
        out = installed.grassd("controllers", "status", *common, "-a", "1-2").stdout
        assert re.findall(r"^address (\d+): table 0x00000007 ", out, re.M) == ["1", "2"], out
    finally:
        _stop(sim)


def test_studio(installed):
    """``grassd studio``: the page, and one characteristic from its simulator."""
    cfg = _config(installed)
    proc = installed.popen("studio", "--port", "0", "--config", cfg,
                           log=installed.work / "studio.log")
    try:
        line = proc.stdout.readline()
        assert line.startswith("grassd studio: http"), (installed.work / "studio.log").read_text()
        url = line.split(": ", 1)[1].strip().split("?")[0]
        with urllib.request.urlopen(url, timeout=60) as r:
            assert r.status == 200 and b"<html" in r.read().lower()
        deadline = time.monotonic() + 240
        while True:  # the simulator process starts Taichi and loads its kernels
            with urllib.request.urlopen(url + "api/state", timeout=60) as r:
                if json.loads(r.read())["ready"]:
                    break
            assert proc.poll() is None and time.monotonic() < deadline, \
                (installed.work / "studio.log").read_text()
            time.sleep(0.3)
        req = urllib.request.Request(url + "api/characteristic", method="POST", data=json.dumps(
            {"ambient_lux": 5000.0, "viewpoint": [170, 2, 0], "lengths_mm": [0, 20]}).encode())
        with urllib.request.urlopen(req, timeout=240) as r:
            body = json.loads(r.read())
        assert len(body["ogcd"]) == 2 and body["ogcd"][1] > 0
    finally:
        _stop(proc)


# ----------------------------------------------------------------------------- uninstall
def test_uninstall_keeps_the_config_and_nothing_else(installed):
    """Last in this module: it removes the venv the tests above run."""
    state = installed.destdir / "var/lib/grassd"
    state.mkdir(parents=True)
    (state / "state.db").write_text("kept")
    config = installed.config.read_text()
    r = _make("uninstall", f"DESTDIR={installed.destdir}")
    assert r.returncode == 0, r.stdout + r.stderr
    left = sorted(str(p.relative_to(installed.destdir))
                  for p in installed.destdir.rglob("*") if not p.is_dir())
    assert left == ["etc/grassd/grassd.toml", "var/lib/grassd/state.db"]
    assert installed.config.read_text() == config
