"""A command started by root never reads, as root, what another user may change in a state
directory (:mod:`grassd.daemon.core.runtime.state_owner`): with a state directory of another
user's it becomes that user (checked on the processes' uids in /proc and on the owner of what it
writes); with root's own, it refuses where another user may change a part of it. Real
processes, real files chowned to uid 65534 (nobody)."""

from __future__ import annotations

import os
import selectors
import subprocess
import sys
import tempfile
import time
import urllib.request
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from grassd.rigs.processes import end_process

pytestmark = pytest.mark.skipif(os.geteuid() != 0, reason="needs root: chowns to another uid")

NOBODY = 65534
SITE_PACKAGES = Path(sys.prefix) / "lib" / f"python{sys.version_info[0]}.{sys.version_info[1]}" \
    / "site-packages"


def _runs_as_nobody(python: str) -> bool:
    """Whether uid 65534 can run ``python`` and import grassd's command line with it."""
    try:
        probe = subprocess.run([python, "-c", "import signal, grassd.daemon.cli.main"],
                               user=NOBODY, group=NOBODY, extra_groups=[], cwd="/",
                               capture_output=True, timeout=60)
    except PermissionError:  # the interpreter itself (pyenv's, under /root)
        return False
    return probe.returncode == 0


@pytest.fixture(scope="module")
def nobody_python() -> Iterator[str]:
    """An interpreter that uid 65534 can run, with this grassd on its path: this one, or (where
    it lies in root's home, as pyenv's) a venv of the system's Python of the same version
    that adds this one's site-packages."""
    if _runs_as_nobody(sys.executable):
        yield sys.executable
        return
    version = f"{sys.version_info[0]}.{sys.version_info[1]}"
    system = Path(f"/usr/bin/python{version}")
    if not system.exists():
        pytest.skip(f"uid 65534 cannot run {sys.executable} and there is no {system}")
    venv = Path(tempfile.mkdtemp(prefix="grassd-nobody-venv-"))
    subprocess.run([str(system), "-m", "venv", "--without-pip", str(venv)], check=True,
                   timeout=120)
    (venv / "lib" / f"python{version}" / "site-packages" / "grassd-tests.pth").write_text(
        f"import site; site.addsitedir({str(SITE_PACKAGES)!r})\n")
    subprocess.run(["chmod", "-R", "a+rX", str(venv)], check=True)
    python = str(venv / "bin" / "python")
    if not _runs_as_nobody(python):
        pytest.skip(f"uid 65534 cannot import grassd from {SITE_PACKAGES}")
    yield python
    subprocess.run(["rm", "-rf", str(venv)], check=False)


@pytest.fixture
def nobody_dir() -> Iterator[Callable[[str], Path]]:
    """Makes directories that belong to uid 65534, under /tmp (which uid 65534 can reach,
    unlike pytest's tmp_path under root's 0700 directory); removed after the test."""
    made: list[Path] = []

    def make(name: str) -> Path:
        path = Path(tempfile.mkdtemp(prefix=f"grassd-{name}-"))
        path.chmod(0o755)
        os.chown(path, NOBODY, NOBODY)
        made.append(path)
        return path

    yield make
    for path in made:
        subprocess.run(["rm", "-rf", str(path)], check=False)


def _uid(pid: int) -> int:
    """The uid of process ``pid``: its real, effective, saved and filesystem uids (the Uid
    line of /proc/PID/status) where they agree, else -1 (a saved uid 0 could go back)."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("Uid:"):
            uids = {int(u) for u in line.split()[1:]}
            return uids.pop() if len(uids) == 1 else -1
    raise AssertionError(f"no Uid in /proc/{pid}/status")


def _children(pid: int) -> list[int]:
    """The processes whose parent is ``pid``."""
    found = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                stat = (entry / "stat").read_text()
            except OSError:
                continue
            if int(stat.rsplit(")", 1)[1].split()[1]) == pid:
                found.append(int(entry.name))
    return found


def _first_line(proc: subprocess.Popen, timeout_s: float) -> str:
    """The first line ``proc`` writes to stdout, within ``timeout_s``."""
    sel = selectors.DefaultSelector()
    sel.register(proc.stdout, selectors.EVENT_READ)
    if not sel.select(timeout_s):
        raise AssertionError(f"nothing on stdout within {timeout_s} s")
    return proc.stdout.readline()


def test_studio_started_by_root_runs_as_the_state_directorys_owner(nobody_python, nobody_dir,
                                                                   tmp_path):
    """`grassd studio --state-dir` by root, the directory nobody's: the server and its
    simulator process both run as uid 65534, and the studio serves."""
    state, cache = nobody_dir("state"), nobody_dir("cache")
    log = tmp_path / "studio.log"
    env = dict(os.environ, GRASSD_CACHE_DIR=str(cache), PYTHONUNBUFFERED="1")
    proc = subprocess.Popen([nobody_python, "-m", "grassd.daemon.cli", "studio", "--state-dir",
                             str(state), "--port", "0"], stdout=subprocess.PIPE,
                            stderr=log.open("wb"), text=True, env=env, cwd="/")
    try:
        line = _first_line(proc, 120)
        assert line.startswith("grassd studio: http"), (line, log.read_text())
        assert _uid(proc.pid) == NOBODY
        deadline = time.monotonic() + 30
        while not (children := _children(proc.pid)):  # the simulator, spawned at start
            assert time.monotonic() < deadline, "no simulator process within 30 s"
            time.sleep(0.1)
        assert [_uid(c) for c in children] == [NOBODY] * len(children)
        url = line.split(": ", 1)[1].strip()
        with urllib.request.urlopen(url + "api/state", timeout=60) as answer:
            assert answer.status == 200
    finally:
        end_process(proc, 30)
    err = log.read_text()
    assert f"grassd studio: runs as uid 65534 (nobody), the owner of {state}, not as root" \
        in err, err
    assert "holds no usable archived bundle" in err  # it read the directory, as nobody


@pytest.mark.parametrize("command", [("calibrate", "--now"), ("measure", "--now"),
                                     ("status",), ("history",), ("show", "--stop")])
def test_one_shot_commands_by_root_run_as_the_owner(nobody_python, nobody_dir, command):
    """The one-shot commands that read the state directory: each becomes its owner first,
    and what `calibrate --now` writes there (lock, database, folders) is the owner's; its
    kernels go to the owner's cache (here nobody's $GRASSD_CACHE_DIR), taken without a word."""
    state, cache = nobody_dir("state"), nobody_dir("cache")
    env = dict(os.environ, GRASSD_CACHE_DIR=str(cache))
    res = subprocess.run([nobody_python, "-m", "grassd.daemon.cli", *command, "--state-dir",
                          str(state)], capture_output=True, text=True, timeout=120, env=env,
                         cwd="/")
    assert (f"grassd {command[0]}: runs as uid 65534 (nobody), the owner of {state}, not as "
            f"root") in res.stderr, res.stderr
    assert "Traceback" not in res.stderr, res.stderr
    written = list(state.rglob("*"))
    if command[0] == "calibrate":
        assert (state / "state.db").exists() and (state / "grassd.lock").exists()
        assert (cache / "taichi").is_dir()  # the owner's own cache ($GRASSD_CACHE_DIR), taken
        assert (cache / "taichi").stat().st_uid == NOBODY and "ignored" not in res.stderr
    assert [p for p in written if p.lstat().st_uid != NOBODY] == []


def _grassd(*args: str, config: Path | None = None) -> subprocess.CompletedProcess:
    extra = ["--config", str(config)] if config else []
    return subprocess.run([sys.executable, "-m", "grassd.daemon.cli", *args, *extra],
                          capture_output=True, text=True, timeout=120)


def test_root_refuses_its_own_state_directory_that_others_may_write(tmp_path):
    """Root's own state directory, but its database writable by every user: the studio
    refuses, naming the file and what to do, before it serves."""
    state = tmp_path / "state"
    state.mkdir()
    (state / "state.db").write_bytes(b"")
    (state / "state.db").chmod(0o666)
    res = _grassd("studio", "--state-dir", str(state), "--port", "0")
    assert res.returncode == 2, res.stderr
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("grassd: error: studio started by root"), lines
    assert f"{state / 'state.db'} is writable by every user (mode 0666)" in lines[0]
    assert "sudo -u USER" in lines[0] and "grassd studio: http" not in res.stdout


def test_root_refuses_a_file_of_another_user_in_its_state_directory(tmp_path):
    """A measurement's correction (applied to every table) that nobody owns, in root's state
    directory: `grassd history` refuses; the group-writable inbox (uploaders') does not count."""
    state = tmp_path / "state"
    (state / "measure").mkdir(parents=True)
    (state / "inbox").mkdir()
    (state / "inbox").chmod(0o2770)
    (state / "inbox" / "upload.exr").write_bytes(b"")
    os.chown(state / "inbox" / "upload.exr", NOBODY, NOBODY)
    assert "runs as" not in _grassd("history", "--state-dir", str(state)).stderr
    correction = state / "measure" / "correction.json"
    correction.write_text("{}")
    os.chown(correction, NOBODY, NOBODY)
    res = _grassd("history", "--state-dir", str(state))
    assert res.returncode == 2
    assert f"{correction} belongs to uid 65534 (nobody), not to uid 0 (root)" in res.stderr


def test_root_refuses_a_configuration_others_may_write(tmp_path):
    """A configuration another user may change could make root run its alert command."""
    from grassd.daemon.core.config.settings import default_config_text

    conf = tmp_path / "grassd.toml"
    conf.write_text(f'state_dir = "{tmp_path / "state"}"\n' + default_config_text())
    os.chown(conf, NOBODY, NOBODY)
    res = _grassd("status", config=conf)
    assert res.returncode == 2
    assert f"reads the configuration {conf}, but {conf} belongs to uid 65534" in res.stderr


def test_studio_as_the_owner_says_which_file_it_cannot_read(nobody_python, nobody_dir,
                                                            tmp_path):
    """An --hdri that only root can read (under pytest's 0700 directory): once the studio runs
    as the state directory's owner, one error naming the file and the user, no traceback."""
    from grassd.sim.hdri import default_site_hdri

    hdri = tmp_path / "site.exr"
    hdri.write_bytes(default_site_hdri().read_bytes())
    res = subprocess.run([nobody_python, "-m", "grassd.daemon.cli", "studio", "--state-dir",
                          str(nobody_dir("state")), "--hdri", str(hdri), "--port", "0"],
                         capture_output=True, text=True, timeout=120, cwd="/")
    assert res.returncode == 2 and "Traceback" not in res.stderr, res.stderr
    assert f"{hdri}: not readable by uid 65534 (nobody), the user the studio runs as" \
        in res.stderr
