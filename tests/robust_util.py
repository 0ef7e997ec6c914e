"""Shared set-up of the tests/test_daemon_robust_*.py files: a small real configuration against
simulated controllers on ptys and a pymodbus lux sensor, bundles written like an uploader does."""

from __future__ import annotations

import os
import shutil
from importlib import resources
from pathlib import Path

from grassd.daemon.config import load_config
from grassd.daemon.service import Service
from grassd.firmware_proto.client import RetryPolicy

ROOT = Path(__file__).resolve().parents[1]
CACHE = os.environ.get("GRASSD_CACHE_DIR", str(ROOT / ".venv" / "grassd-cache"))
SITE = Path(str(resources.files("grassd.sim").joinpath("data/default_site.exr")))


def write_config(path: Path, state: Path, cfg, extra: str = "", interval: float = 0,
                 lux: str = "modbus", light_extra: str = "") -> Path:
    """A tiny but real configuration (one viewpoint, 64 samples) for simulated hardware ``cfg``."""
    ctrls = "".join(f'[[controllers]]\nport = "{c.port}"\naddress = {c.address}\n'
                    f'pixels = "{c.pixels[0][0]}-{c.pixels[0][1]}"\n' for c in cfg.controllers)
    path.write_text(f"""state_dir = "{state}"
cache_dir = "{CACHE}"
[site]
latitude = 52.0
longitude = 13.0
[display]
rows = 4
cols = 8
{ctrls}
[[viewpoints]]
h_cm = 170
d_m = 2
[light]
inbox = "inbox"
lux = "{lux}"
settle_s = 0
{light_extra}
[light.modbus]
port = {cfg.light.modbus.port}
words = 2
scale = 0.1
timeout_s = 0.3
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


def drop(inbox: Path, name: str, lux: float | None = 1000.0, mode: int | None = None) -> Path:
    """Write a directory bundle as an uploader does: hidden name, manifest last, rename."""
    d = inbox / f".{name}"
    d.mkdir(parents=True)
    shutil.copy(SITE, d / "sky.exr")
    m = f'timestamp = 2026-03-01T12:00:00+01:00\nhdri = "sky.exr"\n# {name}\n'
    if lux is not None:
        m += f"ambient_lux = {lux}\n"
    (d / "manifest.toml").write_text(m)
    if mode is not None:
        os.chmod(d, mode)
    os.rename(d, inbox / name)
    return inbox / name


def service(path: Path, **kw) -> Service:
    """An in-process daemon for config file ``path`` (Taichi initialised, short timeouts)."""
    from grassd.daemon.calibrate import init_backend

    policy = RetryPolicy(timeout_s=0.1, retries=1, restarts=1, readback_retries=2)
    svc = Service(load_config(path), config_path=path, policy=policy, **kw)
    init_backend(svc.cfg)
    return svc
