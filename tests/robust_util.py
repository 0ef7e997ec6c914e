"""Shared set-up of the daemon tests (tests/test_daemon_*.py): a small real configuration
against simulated controllers on ptys and a pymodbus lux sensor (the ``hw`` fixture in
conftest.py), bundles written like an uploader does, an in-process service."""

from __future__ import annotations

import os
import shutil
import time
from importlib import resources
from pathlib import Path
from typing import Any

from grassd.daemon.config.settings import load_config
from grassd.daemon.hardware.simulated import hardware_toml
from grassd.daemon.runtime.service import Service
from grassd.firmware_proto.client import RetryPolicy

ROOT = Path(__file__).resolve().parents[1]
CACHE = os.environ.get("GRASSD_CACHE_DIR", str(ROOT / ".venv" / "grassd-cache"))
SITE = Path(str(resources.files("grassd.sim").joinpath("data/default_site.exr")))
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


#: the one viewpoint of :func:`write_config`; TWO_VIEWS adds a second one off-axis
ONE_VIEW = "[[viewpoints]]\nh_cm = 170\nd_m = 2\n"
TWO_VIEWS = ONE_VIEW + "[[viewpoints]]\nh_cm = 165\nd_m = 3\ntheta_deg = 20\n"


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
    """An in-process daemon for config file ``path`` (Taichi initialised, short timeouts)."""
    from grassd.daemon.calibration.calibrate import init_backend

    policy = RetryPolicy(timeout_s=0.1, retries=1, restarts=1, readback_retries=2)
    svc = Service(load_config(path), config_path=path, policy=policy, **kw)
    init_backend(svc.cfg)
    return svc


def tick_until(svc: Service, cond, timeout: float = 15.0) -> None:
    """Run main-loop passes of ``svc`` until ``cond()`` holds (fails after ``timeout`` s)."""
    deadline = time.monotonic() + timeout
    while not cond():
        assert time.monotonic() < deadline, "condition not reached"
        svc.tick()
        time.sleep(0.05)
