"""``grassd show FILE`` (the content feature, :mod:`grassd.daemon.content`): a picture or
animation on the display, through the running daemon (control socket ``content_show``), or
played here on the configured controllers when no daemon runs."""

from __future__ import annotations

import time
from pathlib import Path

import click

from grassd.daemon.core.errors import DaemonError


class NothingShown(DaemonError):
    """``grassd show`` without a daemon played its picture, but no controller took a frame
    (ports missing or silent, no table on them)."""


_CONFIG_HELP = ("configuration file (default: /etc/grassd/grassd.toml if it exists, else the "
                "embedded default)")


@click.command("show")
@click.argument("file", required=False,
                type=click.Path(exists=True, dir_okay=False, path_type=Path))
@click.option("--duration", "duration_s", type=click.FloatRange(0.1, 86400.0),
              help="seconds to show it (default: one pass of an animation, at least 10 s)")
@click.option("--stop", is_flag=True,
              help="end what the daemon shows for grassd show or a script now (its next "
                   "source takes over)")
@click.option("--config", "config_path", type=click.Path(dir_okay=False), help=_CONFIG_HELP)
@click.option("--state-dir", type=click.Path(file_okay=False),
              help="override the state directory")
def show(file: Path | None, duration_s: float | None, stop: bool, config_path: str | None,
         state_dir: str | None) -> None:
    """Show a picture or animation (PNG, JPEG, GIF, APNG) on the display, through the
    running daemon or here when none runs."""
    from grassd.daemon.core.errors import DaemonNotRunning
    from grassd.daemon.core.runtime.control import request
    from grassd.daemon.core.runtime.state_owner import config_as_state_owner

    if stop == (file is not None):
        raise click.UsageError("give a picture FILE to show, or --stop (not both)")
    cfg = config_as_state_owner(config_path, state_dir, "show")
    if stop:
        try:
            request(cfg.control_socket, {"cmd": "content_stop"})
        except DaemonNotRunning:
            raise click.ClickException("no daemon runs, so nothing is shown for grassd show "
                                       "(one played here ends with its command)") from None
        click.echo("grassd: the daemon's next source shows now")
        return
    assert file is not None
    req = {"cmd": "content_show", "path": str(file.resolve())}
    if duration_s is not None:
        req["duration_s"] = duration_s
    try:
        ans = request(cfg.control_socket, req)
    except DaemonNotRunning:
        _play_here(cfg, file, duration_s)
        return
    click.echo(f"grassd: the daemon shows {file.name} ({ans.get('frames')} frame(s))")


def _play_here(cfg, file: Path, duration_s: float | None) -> None:
    """Play ``file`` on ``cfg``'s controllers from this process, then close them."""
    from grassd.daemon.content.config import ContentConfig
    from grassd.daemon.content.pictures import load_animation
    from grassd.daemon.core.runtime.statelock import StateLock
    from grassd.daemon.core.store.layout import StateLayout

    content = cfg.content or ContentConfig()
    cfg = cfg.replace(content=content)
    anim = load_animation(file, cfg.display.rows, cfg.display.cols,
                          content.max_picture_mib << 20)
    duration = duration_s if duration_s is not None else max(anim.length_s, 10.0)
    layout = StateLayout(cfg.state_dir)
    cfg.state_dir.mkdir(parents=True, exist_ok=True)
    with StateLock(cfg.state_dir, "grassd show") as lock:  # the controllers are ours now
        lock.note_ports(cfg.serial_ports)
        _play_on_controllers(cfg, layout, anim, file.name, duration)


def _play_on_controllers(cfg, layout, anim, name: str, duration: float) -> None:
    """Play ``anim`` for ``duration`` s on ``cfg``'s controllers, holding the state lock."""
    from grassd.daemon.content.feature import ContentPlayback
    from grassd.daemon.content.frames import FrameOutput
    from grassd.daemon.core.hardware.fleet import Fleet
    from grassd.daemon.core.store.history import History

    history = History(layout.db)
    fleet = Fleet(cfg.controllers)
    sink = FrameOutput(cfg.controllers, cfg.display.pixel_count,
                       fps=float(cfg.content.fps), fleet=fleet)
    try:
        player = ContentPlayback(cfg, sink, history, layout.reports, live=False).player
        player.show(anim, duration)
        click.echo(f"grassd: showing {name} here for {duration:g} s (no daemon runs)")
        player.start()
        time.sleep(duration)
        player.stop()
        shown = sink.stats().frames_shown
    finally:
        sink.close()
        fleet.close()
        history.close()
    if shown == 0:
        raise NothingShown(f"no controller took a frame of {name} in {duration:g} s: check "
                           "that the [[controllers]] ports exist and answer (grassd "
                           "controllers), and that they hold a table (grassd calibrate --now)")
    click.echo(f"grassd: {shown} frame(s) shown")
