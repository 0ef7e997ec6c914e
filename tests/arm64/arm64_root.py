"""A Debian arm64 root run under qemu-user, with grassd installed in it from this checkout: the
arm64 tier's machine (tests/arm64/, docs/operating/arm64.md).

The root is Debian bookworm (``debootstrap --arch=arm64 --foreign --variant=minbase`` with
python3 and python3-venv), built once and kept in :data:`ROOT` (``build/arm64-root``, or
``$GRASSD_ARM64_ROOT``). It needs no binfmt_misc: the first stage's packages are unpacked with
``dpkg-deb`` (no maintainer script runs; none of these needs one), and every arm64 program runs
as ``chroot ROOT qemu-aarch64-static PROGRAM``, in a private mount namespace (``unshare``) that
sees the host's /dev (the daemon's ptys), a fresh /proc and /sys, and the directories a test
binds in. Nothing is mounted in the host's namespace, so nothing is left mounted when a run dies.
No program run there may start another arm64 program (there is no binfmt handler to run it).

grassd goes into the venv ``/opt/grassd`` by the root's own pip (arm64, Python 3.11): a wheel
built from the checkout, its dependencies pinned by ``uv pip compile --python-platform
aarch64-manylinux_2_28`` (markers evaluated for aarch64, so Taichi is left out) and fetched by the
host's pip into a wheel directory beside the root, since pip downloading under qemu-user is slow.
The root's pip then resolves from that directory only (``--no-index``): were Taichi required on
aarch64, the install would fail there. The Dask packages are pinned to the host's versions, so
the daemon in the root speaks to the host's Dask worker.
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import os
import re
import shutil
import subprocess
import sys
import time
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
#: the root, kept across runs (build/ is ignored by git and removed by `make clean`)
ROOT = Path(os.environ.get("GRASSD_ARM64_ROOT", REPO / "build" / "arm64-root"))
#: the aarch64 wheels of the dependencies, fetched on the host (kept across runs)
WHEELS = ROOT.parent / f"{ROOT.name}-wheels"
SUITE = "bookworm"
MIRROR = os.environ.get("GRASSD_DEBIAN_MIRROR", "http://deb.debian.org/debian")
PACKAGES = ("python3", "python3-venv")
QEMU = "/usr/bin/qemu-aarch64-static"
#: the venv grassd is installed in, inside the root
VENV = "/opt/grassd"
PYTHON = f"{VENV}/bin/python"
#: the platform uv resolves for (Debian bookworm's glibc is 2.36)
UV_PLATFORM = "aarch64-manylinux_2_28"
#: pinned to the host's versions: the Dask client in the root and the worker on the host must
#: agree on Dask's wire format (and numpy's arrays cross it)
SAME_AS_HOST = ("dask", "distributed", "cloudpickle", "msgpack", "toolz", "tornado", "numpy")
#: the root's layout: a change rebuilds it
_ROOT_KEY = f"{SUITE} {MIRROR} {' '.join(PACKAGES)} v1"
#: the environment of programs in the root (none of the host's, e.g. its pip configuration)
ENV = {"PATH": f"{VENV}/bin:/usr/sbin:/usr/bin:/sbin:/bin", "HOME": "/root",
       "LANG": "C.UTF-8", "PYTHONDONTWRITEBYTECODE": "", "PIP_DISABLE_PIP_VERSION_CHECK": "1"}
_HOW = "apt-get install debootstrap qemu-user-static; as root"


def _which(tool: str) -> str | None:
    """``tool``'s path, looking in the sbin directories too (a root shell may lack them)."""
    return shutil.which(tool, path=f"{os.environ.get('PATH', '')}:/usr/sbin:/sbin")


def missing_reason() -> str | None:
    """One line saying why the arm64 tier cannot run here, or None when it can."""
    tools = ["debootstrap", "dpkg-deb", "chroot", "unshare", "mount"]
    lacking = [t for t in tools if _which(t) is None]
    if not os.path.exists(QEMU):
        lacking.append(QEMU)
    if lacking:
        return f"arm64 tier skipped: {', '.join(lacking)} not found ({_HOW})"
    if os.geteuid() != 0:
        return f"arm64 tier skipped: chroot and mount need root ({_HOW})"
    return None


def _log(msg: str) -> None:
    print(f"arm64 root: {msg}", file=sys.stderr, flush=True)


@contextlib.contextmanager
def _locked() -> Iterator[None]:
    """Hold the root's lock (another test process may be building or installing it)."""
    ROOT.parent.mkdir(parents=True, exist_ok=True)
    with open(ROOT.parent / f".{ROOT.name}.lock", "w") as fh:
        fcntl.flock(fh, fcntl.LOCK_EX)
        yield


def _run(argv: Sequence[str], timeout: float, **kw) -> subprocess.CompletedProcess:
    """Run ``argv`` (a host or root program); fail with its output's tail when it fails."""
    p = subprocess.run(list(argv), capture_output=True, text=True, timeout=timeout, **kw)
    if p.returncode != 0:
        raise RuntimeError(f"{' '.join(map(str, argv[:8]))} ... exited with {p.returncode}:\n"
                           f"{(p.stdout + p.stderr)[-4000:]}")
    return p


def ensure_root() -> float:
    """Build :data:`ROOT` unless it is there and current; returns the seconds spent building
    (0 when it was reused). Built beside it, then renamed: a half-built root is never used."""
    with _locked():
        ready = ROOT / ".grassd-root"
        if ready.exists() and ready.read_text() == _ROOT_KEY:
            _mount_points(ROOT)
            return 0.0
        t0 = time.monotonic()
        part = ROOT.parent / f"{ROOT.name}.partial"
        for d in (part, ROOT):
            if d.exists():
                shutil.rmtree(d)
        _log(f"debootstrap {SUITE} arm64 into {part} (from {MIRROR})")
        _run([str(_which("debootstrap")), "--arch=arm64", "--foreign", "--variant=minbase",
              f"--include={','.join(PACKAGES)}", SUITE, str(part), MIRROR], timeout=1200,
             env={**os.environ, "PATH": f"{os.environ.get('PATH', '')}:/usr/sbin:/sbin"})
        # the second stage would run the packages' maintainer scripts under qemu (binfmt_misc
        # needed); unpacking is all these packages need
        base = (part / "debootstrap" / "base").read_text().split()
        debs = sorted((part / "var/cache/apt/archives").glob("*.deb"))
        names = {d.name.split("_")[0]: d for d in debs}
        for name in (n for n in base if n in names):
            data = subprocess.run(["dpkg-deb", "--fsys-tarfile", str(names[name])],
                                  capture_output=True, check=True).stdout
            subprocess.run(["tar", "-C", str(part), "--keep-directory-symlink", "-xf", "-"],
                           input=data, check=True)
        _mount_points(part)
        shutil.copy2(QEMU, part / QEMU.lstrip("/"))
        shutil.copy2("/etc/resolv.conf", part / "etc/resolv.conf")  # chroot shares the network
        for d in ("var/cache/apt/archives", "debootstrap"):
            shutil.rmtree(part / d, ignore_errors=True)
        (part / "var/cache/apt/archives").mkdir(parents=True)
        _run(_in_root_argv(part, {}, ["/usr/bin/python3", "-m", "venv", "--without-pip",
                                      VENV]), env=ENV, timeout=600)
        (part / ".grassd-root").write_text(_ROOT_KEY)
        part.rename(ROOT)
        took = time.monotonic() - t0
        _log(f"built in {took:.0f} s")
        return took


def _mount_points(root: Path) -> None:
    """Make /dev, /proc and /sys of ``root`` directories: the first stage links ``proc`` to
    the host's /proc (meant for its second stage), which the chroot would see as a loop."""
    for name in ("dev", "proc", "sys"):
        d = root / name
        if d.is_symlink():
            d.unlink()
        d.mkdir(exist_ok=True)


def _in_root_argv(root: Path, binds: Mapping[Path, str], argv: Sequence[str]) -> list[str]:
    """The host command that runs arm64 ``argv`` in ``root`` under qemu-user, in a private
    mount namespace with /dev, /proc, /sys and ``binds`` (host dir -> path in the root)."""
    script = ['set -e', 'r=$1; shift',
              'mount --rbind /dev "$r/dev"', 'mount -t proc proc "$r/proc"',
              'mount --rbind /sys "$r/sys"']
    args: list[str] = []
    for i, (host, inside) in enumerate(binds.items()):
        script.append(f'mkdir -p "$r{inside}" && mount --bind "${i + 1}" "$r{inside}"')
        args.append(str(host))
    script.append(f"shift {len(args)}")
    script.append(f'exec chroot "$r" {QEMU} "$@"')
    return ["unshare", "--mount", "--propagation", "private", "sh", "-c", "\n".join(script),
            "sh", str(root), *args, *argv]


def in_root(argv: Sequence[str], binds: Mapping[Path, str] | None = None) -> list[str]:
    """The host command that runs arm64 program ``argv`` (absolute path in :data:`ROOT`
    first) there under qemu-user; ``binds``: host directory -> its path in the root. Run it
    with ``env=ENV``. It runs in the same process (exec), so a signal sent to it reaches the
    arm64 program."""
    return _in_root_argv(ROOT, binds or {}, argv)


def run_in_root(argv: Sequence[str], binds: Mapping[Path, str] | None = None,
                timeout: float = 600) -> subprocess.CompletedProcess:
    """Run arm64 ``argv`` in :data:`ROOT` and return it (raises with its output on failure)."""
    return _run(in_root(argv, binds), env=ENV, timeout=timeout)


def _host_versions() -> dict[str, str]:
    from importlib.metadata import version

    return {n: version(n) for n in SAME_AS_HOST}


def _lock_dependencies(out: Path) -> Path:
    """``uv pip compile`` of the checkout's dependencies for aarch64 (Python 3.11, wheels only,
    :data:`SAME_AS_HOST` pinned to the host's versions) into ``out/requirements.txt``."""
    constraints = out / "same-as-host.txt"
    constraints.write_text("".join(f"{n}=={v}\n" for n, v in _host_versions().items()))
    req = out / "requirements.txt"
    _run([uv(), "pip", "compile", str(REPO / "pyproject.toml"), "--python-platform",
          UV_PLATFORM, "--python-version", "3.11", "--only-binary", ":all:", "-c",
          str(constraints), "--no-header", "--no-annotate", "-q", "-o", str(req)],
         timeout=300, cwd=REPO)
    return req


def uv() -> str:
    """The uv next to this Python (the test extra installs it), else the one on PATH."""
    here = Path(sys.executable).parent / "uv"
    found = str(here) if here.exists() else shutil.which("uv")
    if found is None:
        raise FileNotFoundError("uv not found (pip install uv; the test extra has it)")
    return found


def install_grassd(work: Path) -> dict[str, float]:
    """Install grassd from this checkout into the root's venv :data:`VENV`, by the root's pip;
    returns the seconds each step took. ``work``: a scratch directory on the host."""
    times: dict[str, float] = {}
    t = time.monotonic()
    wheel_dir = work / "wheel"
    # built from a copy: setuptools builds in the source's build/, which another test may be
    # using at the same time
    src = work / "src"
    shutil.copytree(REPO, src, ignore=shutil.ignore_patterns(
        ".git", ".venv", "build", "site", "out", "*.egg-info", "__pycache__", ".*_cache",
        ".hypothesis"))
    _run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "-w", str(wheel_dir),
          str(src)], timeout=600)
    [wheel] = wheel_dir.glob("grassd-*.whl")
    times["wheel"] = time.monotonic() - t
    t = time.monotonic()
    req = _lock_dependencies(work)
    assert not re.search(r"(?im)^taichi==", req.read_text()), "taichi resolved for aarch64"
    times["lock"] = time.monotonic() - t
    with _locked():
        t = time.monotonic()
        # the host's pip fetches the aarch64 wheels (no dependencies: uv resolved them)
        WHEELS.mkdir(parents=True, exist_ok=True)
        _run([sys.executable, "-m", "pip", "download", "-q", "--no-deps", "--only-binary",
              ":all:", "--platform", "manylinux_2_28_aarch64", "--python-version", "3.11",
              "--implementation", "cp", "--abi", "cp311", "-r", str(req), "-d", str(WHEELS)],
             timeout=1200)
        times["download"] = time.monotonic() - t
        t = time.monotonic()
        digest = hashlib.sha256(req.read_bytes()).hexdigest()[:16]
        deps_ok = ROOT / VENV.lstrip("/") / ".grassd-deps"
        binds = {WHEELS: "/mnt/wheels", work: "/mnt/work"}
        pip = [PYTHON, "-m", "pip"]
        if not (ROOT / PYTHON.lstrip("/")).exists() or not (ROOT / VENV.lstrip("/") / "bin"
                                                             / "pip").exists():
            # the venv's pip, from the wheel Debian ships (python3-pip-whl)
            [pipwhl] = (ROOT / "usr/share/python-wheels").glob("pip-*.whl")
            run_in_root([PYTHON, f"/usr/share/python-wheels/{pipwhl.name}/pip", "install",
                         "-q", "--no-index", f"/usr/share/python-wheels/{pipwhl.name}"])
        wheels = ["--no-index", "--find-links", "/mnt/wheels", "--only-binary", ":all:"]
        if not deps_ok.exists() or deps_ok.read_text() != digest:
            # one resolution by the root's pip of grassd's requirements for aarch64, against
            # these wheels only: it fails here if a requirement (Taichi) has no aarch64 wheel
            run_in_root([*pip, "install", "-q", "--no-compile", *wheels, "-r",
                         "/mnt/work/requirements.txt", f"/mnt/work/wheel/{wheel.name}"], binds,
                        timeout=2400)
            deps_ok.write_text(digest)
        else:  # the same dependencies: grassd anew, then pip checks its requirements here
            run_in_root([*pip, "install", "-q", "--no-compile", *wheels, "--no-deps",
                         "--force-reinstall", f"/mnt/work/wheel/{wheel.name}"], binds)
            run_in_root([*pip, "check"])
        times["pip install in the root"] = time.monotonic() - t
    return times

