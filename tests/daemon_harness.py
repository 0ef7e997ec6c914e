"""The daemon tests' harness (tests/daemon/): a small real configuration against simulated
controllers on ptys and a pymodbus lux sensor (the ``hw`` fixture in conftest.py), a 2 x 2
display on two controllers, bundles written like an uploader does, an in-process service, and a
real tmpfs to fill up."""

from __future__ import annotations

import contextlib
import os
import shutil
import subprocess
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from grassd.daemon.core.config.settings import load_config
from grassd.daemon.core.runtime.service import Service
from grassd.firmware_proto.client import RetryPolicy
from grassd.rigs.simulated_site import hardware_toml
from grassd.sim.hdri import default_site_hdri

ROOT = Path(__file__).resolve().parents[1]
CACHE = os.environ.get("GRASSD_CACHE_DIR", str(ROOT / ".venv" / "grassd-cache"))
SITE = default_site_hdri()


def truncated_exr() -> bytes:
    """The default site's EXR cut two thirds in: its header is sound, so the inbox claims the
    bundle, and its run is rejected by the renderer's reader (a run row with status rejected)."""
    data = SITE.read_bytes()
    return data[:len(data) * 2 // 3]
#: top of a configuration: state directory "state" beside the file, the shared kernel cache,
#: a site in Munich
HEAD = f"""
state_dir = "state"
cache_dir = "{CACHE}"
[site]
latitude = 48.1
longitude = 11.6
timezone = "Europe/Berlin"
"""


#: short controller timeouts for tests (the simulated controllers answer at once)
POLICY = RetryPolicy(timeout_s=0.1, retries=1, restarts=1, readback_retries=2)

#: the one viewpoint of :func:`write_config`; TWO_VIEWS adds a second one off-axis
ONE_VIEW = "[[viewpoints]]\nh_cm = 170\nd_m = 2\n"
TWO_VIEWS = ONE_VIEW + "[[viewpoints]]\nh_cm = 165\nd_m = 3\ntheta_deg = 20\n"


def display_2x2(head: str = HEAD, *, ports: tuple[str, str] = ("/dev/grassd-test-bus0",
                                                                  "/dev/grassd-test-bus1"),
                viewpoints: str = ONE_VIEW, samples: int = 256, seed: int = 3,
                replicates: int = 4, layouts: int | None = None, max_rounds: int = 1,
                extra: str = "") -> str:
    """Config text after ``head``: a 2 x 2 display driven by two controllers (one bus each on
    ``ports``, pixels 0-1 and 2-3), lux from the manifest, no schedule, few ``samples`` per
    replicate, 5 lengths, ``max_rounds`` closed-loop rounds; ``extra`` (further tables) last."""
    sim = f"samples = {samples}\nseed = {seed}\nlengths = 5\n"
    if layouts is not None:
        sim += f"layouts = {layouts}\n"
    return head + f"""[display]
rows = 2
cols = 2
[[controllers]]
port = "{ports[0]}"
address = 1
pixels = "0-1"
[[controllers]]
port = "{ports[1]}"
address = 2
pixels = "2-3"
{viewpoints}[light]
inbox = "inbox"
lux = "manifest"
settle_s = 0
[schedule]
interval_s = 0
[simulation]
{sim}[calibration]
replicates = {replicates}
max_jump_mm = 20.0
check_levels = 5
max_rounds = {max_rounds}
{extra}"""


#: a 2 x 2 display driven by two controllers (one bus each, pixels 0-1 and 2-3), one viewpoint,
#: lux from the manifest, low sample counts (seed 3), one closed-loop round
DISPLAY_2X2 = display_2x2()


def write_config(path: Path, state: Path, cfg, extra: str = "", interval: float = 0,
                 lux: str = "modbus", light_extra: str = "", views: str = ONE_VIEW,
                 sensor_timeout_s: float = 0.3) -> Path:
    """A tiny but real configuration (``views``, 64 samples) for simulated hardware ``cfg``."""
    path.write_text(f"""state_dir = "{state}"
cache_dir = "{CACHE}"
[site]
latitude = 52.0
longitude = 13.0
{hardware_toml(cfg)}{views}[light]
inbox = "inbox"
lux = "{lux}"
settle_s = 0
{light_extra}
[light.modbus]
port = {cfg.light.modbus.port}
words = 2
scale = 0.1
timeout_s = {sensor_timeout_s}
retries = 0
[schedule]
interval_s = {interval}
[simulation]
samples = 64
lengths = 6
[calibration]
check_levels = 5
max_rounds = 1
replicates = 2
max_jump_mm = 20.0
{extra}""")
    return path


def drop(inbox: Path, name: str, lux: float | None = 1000.0, mode: int | None = None,
         timestamp: str = "2026-03-01T12:00:00+01:00") -> Path:
    """Write a directory bundle as an uploader does: hidden name, manifest last, rename.
    ``timestamp``: the manifest's (when the light was captured)."""
    d = inbox / f".{name}"
    d.mkdir(parents=True)
    shutil.copy(SITE, d / "sky.exr")
    m = f'timestamp = {timestamp}\nhdri = "sky.exr"\n# {name}\n'
    if lux is not None:
        m += f"ambient_lux = {lux}\n"
    (d / "manifest.toml").write_text(m)
    if mode is not None:
        os.chmod(d, mode)
    os.rename(d, inbox / name)
    return inbox / name


def drop_midsummer(inbox: Path, name: str, lux: float = 8000.0) -> None:
    """Write a directory bundle of the site HDRI at noon on 21 June 2026 with ``lux`` (lux) in
    its manifest, as an uploader does (hidden name, then rename)."""
    d = inbox / f".{name}"
    d.mkdir(parents=True)
    shutil.copy(SITE, d / "sky.exr")
    (d / "manifest.toml").write_text(
        f'timestamp = 2026-06-21T12:00:00+02:00\nhdri = "sky.exr"\nambient_lux = {lux}\n')
    os.rename(d, inbox / name)


def journal_entry(svc: Service, name: str):
    """The one ingest journal row of the bundle uploaded as ``name``."""
    [j] = [j for j in svc.history.journal() if j.name == name]
    return j


def reported(svc: Service) -> set:
    """(table id, CRC) that the simulated controllers report over their ptys."""
    return {(st.table_id, st.table_crc) for _, st, _ in svc.fleet.read_all()}


def after_first_bundle(tmp_path: Path, cfg, **kw) -> tuple[Service, Any]:
    """A service (``kw`` as for :func:`service`) on :func:`write_config`'s configuration for
    ``cfg`` in ``tmp_path``, after one main-loop pass processed a first bundle "b1" (1000 lux):
    returns it and the current table that run made (asserted to exist)."""
    svc = service(write_config(tmp_path / "g.toml", tmp_path / "state", cfg), **kw)
    drop(svc.cfg.light.inbox, "b1", lux=1000.0)
    svc.tick()
    table = svc.history.current_table()
    assert table is not None
    return svc, table


def service(path: Path, **kw) -> Service:
    """An in-process daemon for config file ``path`` with the daemon's features (Taichi
    initialised, short timeouts)."""
    from grassd.daemon.cli.features import daemon_features
    from grassd.daemon.core.calibration.calibrate import init_backend

    kw.setdefault("policy", POLICY)
    kw.setdefault("features", daemon_features())
    svc = Service(load_config(path), config_path=path, **kw)
    init_backend(svc.cfg)
    return svc


def tick_until(svc: Service, cond, timeout: float = 15.0) -> None:
    """Run main-loop passes of ``svc`` until ``cond()`` holds (fails after ``timeout`` s)."""
    deadline = time.monotonic() + timeout
    while not cond():
        assert time.monotonic() < deadline, "condition not reached"
        svc.tick()
        time.sleep(0.05)


@contextlib.contextmanager
def tmpfs(d: Path, size: str = "16m"):
    """A real tmpfs mounted at ``d`` (skips unless we may mount)."""
    d.mkdir(parents=True, exist_ok=True)
    if os.geteuid() != 0 or subprocess.run(
            ["mount", "-t", "tmpfs", "-o", f"size={size},mode=0755", "tmpfs", str(d)],
            capture_output=True).returncode != 0:
        pytest.skip("needs root and mount(8) to fill a real file system")
    try:
        yield d
    finally:
        subprocess.run(["umount", "-l", str(d)], check=True)


@contextlib.contextmanager
def full(d: Path):
    """Fill the file system of ``d`` to its last block; free it again on exit."""
    filler = d / "filler"
    with contextlib.suppress(OSError), open(filler, "wb") as fh:
        while True:
            fh.write(b"\0" * 65536)
            fh.flush()
    with contextlib.suppress(OSError), open(filler, "ab") as fh:  # the last partial block
        while True:
            fh.write(b"\0" * 512)
            fh.flush()
    try:
        yield
    finally:
        filler.unlink()


def wait_for(cond: Callable[[], Any], timeout: float, what: str, *, poll: float = 0.05,
             check: Callable[[], None] | None = None,
             context: Callable[[], str] | None = None) -> Any:
    """Poll ``cond`` every ``poll`` s until it returns something true and return that, for at
    most ``timeout`` s. ``check`` runs after each poll that is not yet true and may raise (a
    process that died); ``context`` adds text (a log tail) to the timeout's message."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        v = cond()
        if v:
            return v
        if check is not None:
            check()
        time.sleep(poll)
    extra = f"\n{context()}" if context is not None else ""
    raise AssertionError(f"timed out after {timeout} s waiting for {what}{extra}")
