"""``grassd check-config``, ``grassd run``, ``grassd status``, ``grassd history`` and
``grassd calibrate --now``: the daemon's command-line face."""

from __future__ import annotations

from pathlib import Path

import click

from grassd.daemon.config import DEFAULT_CONFIG_PATH, Config, load_config, load_default_config

_CONFIG_HELP = (f"configuration file (default {DEFAULT_CONFIG_PATH}; "
                "the embedded default when that is absent)")


def resolve_config(path: str | None, state_dir: str | None = None) -> Config:
    """Load ``path`` (or /etc/grassd/grassd.toml, or the embedded default when that is absent)."""
    if path is not None:
        cfg = load_config(path)
    elif DEFAULT_CONFIG_PATH.exists():
        cfg = load_config(DEFAULT_CONFIG_PATH)
    else:
        cfg = load_default_config()
    return cfg.with_state_dir(Path(state_dir).absolute()) if state_dir else cfg


@click.command("check-config")
@click.option("--config", "config_path", type=click.Path(dir_okay=False), help=_CONFIG_HELP)
def check_config(config_path: str | None) -> None:
    """Validate the configuration file and print a summary (exit 2 naming key and line if bad)."""
    cfg = resolve_config(config_path)
    click.echo(f"{cfg.source}: OK")
    click.echo(f"  display: {cfg.display.rows} x {cfg.display.cols} pixels, "
               f"pitch {cfg.display.pitch_mm} mm")
    for c in cfg.controllers:
        ranges = ",".join(f"{a}-{b}" if a != b else str(a) for a, b in c.pixels)
        click.echo(f"  controller {c.port} addr {c.address} @ {c.baud} baud: pixels {ranges}")
    for v in cfg.viewpoints:
        click.echo(f"  viewpoint h={v.h_cm} cm d={v.d_m} m theta={v.theta_deg} deg "
                   f"weight={v.weight}")
    lux = cfg.light.lux
    if cfg.light.modbus is not None:
        m = cfg.light.modbus
        where = f"{m.host}:{m.port}" if m.mode == "tcp" else m.serial_port
        lux += f" (modbus {m.mode} {where} unit {m.unit} fc {m.function_code} reg {m.register})"
    click.echo(f"  inbox: {cfg.light.inbox}; lux from {lux}")
    click.echo(f"  state: {cfg.state_dir}; cache: {cfg.cache_dir}; socket: {cfg.control_socket}")
