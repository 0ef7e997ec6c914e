"""``grassd studio``: the interactive view of a site in a browser (:mod:`grassd.daemon.studio`)."""

from __future__ import annotations

import asyncio
import os
import secrets
import socket
from pathlib import Path
from typing import TYPE_CHECKING

import click

from grassd.daemon.core.config.settings import CONFIG_OPTION_HELP, resolve_config

if TYPE_CHECKING:
    from grassd.daemon.core.config.settings import Config
    from grassd.daemon.studio.lights import LightSource
    from grassd.daemon.studio.process import StudioArgs

#: The port the studio listens on unless told otherwise.
DEFAULT_PORT: int = 8420


def _active_table(state_dir: Path):
    """The daemon's active table (256,) [um] from the state directory's history, or None."""
    from grassd.daemon.core.store.history import History
    from grassd.daemon.core.store.layout import StateLayout

    db = StateLayout(state_dir).db
    if not db.is_file():
        return None
    with History(db) as history:
        run = history.current_table()
    return None if run is None or run.lengths_um is None else list(run.lengths_um)


@click.command("studio")
@click.option("--config", "config_path", type=click.Path(dir_okay=False),
              help=CONFIG_OPTION_HELP)
@click.option("--state-dir", type=click.Path(file_okay=False, path_type=Path),
              help="The daemon's state directory (an existing one): its usable archived "
                   "bundles become light sources and its active table can be shown.")
@click.option("--hdri", type=click.Path(dir_okay=False, exists=True, path_type=Path),
              help="An equirectangular panorama (.exr or .hdr) to light the display with.")
@click.option("--pixel", "pixel_file", type=click.Path(dir_okay=False, path_type=Path),
              help="The pixel's materials from a grassd fit result (its JSON report or "
                   "--toml file) over the config's [display.pixel].")
@click.option("--port", type=click.IntRange(0, 65535), default=DEFAULT_PORT, show_default=True,
              help="TCP port (0: any free one).")
@click.option("--host", default="127.0.0.1", show_default=True,
              help="Address to bind. Any other than 127.0.0.1 needs the token printed at "
                   "start.")
@click.option("--arch", type=click.Choice(["cpu", "gpu"]), default="cpu", show_default=True)
def studio(config_path, state_dir, hdri, pixel_file, port, host, arch) -> None:
    """Serve the interactive studio: move the eye, change the light, see the pixel, its
    colour characteristic, the table and a picture on the display. Prints its URL."""
    from grassd.daemon.studio.lights import Lights
    from grassd.daemon.studio.process import StudioArgs
    from grassd.daemon.studio.server import LOCAL_HOST
    from grassd.sim.errors import require_renderer

    require_renderer()  # first: without Taichi nothing below matters (one line, exit 2)
    cfg = _config(config_path, state_dir)
    _check_readable(hdri=hdri, pixel=pixel_file)
    sources, active = _light_sources(cfg, hdri, state_dir)
    fields, pixel_source = None, "config"
    if pixel_file is not None:
        from grassd.daemon.offline.fit import load_pixel_fields

        fields, pixel_source = load_pixel_fields(pixel_file), f"fit: {pixel_file.name}"
    Lights(sources)  # at least one
    args = StudioArgs(config_path, str(state_dir) if state_dir else None, tuple(sources),
                      pixel_fields=fields, pixel_source=pixel_source,
                      active_um=None if active is None else tuple(int(v) for v in active),
                      arch=arch)
    token = None if host == LOCAL_HOST else secrets.token_urlsafe(18)
    said = (f"light: {sources[0].label}; pixel: {pixel_source}; {len(sources)} light "
            f"source(s); Ctrl-C stops")
    try:
        asyncio.run(_serve(args, host, port, token, said))
    except KeyboardInterrupt:
        pass
    except OSError as exc:
        raise click.ClickException(f"cannot listen on {host}:{port}: {exc.strerror or exc}; "
                                   f"choose another --port or --host") from None


def _config(config_path: str | None, state_dir: Path | None) -> Config:
    """The studio's config: read as the state directory's owner where one is given (it must
    exist: a typo would serve the default site)."""
    from grassd.daemon.core.runtime.state_owner import config_as_state_owner

    if state_dir is not None and not state_dir.is_dir():
        raise click.BadParameter(
            f"{state_dir}: no such directory; give the daemon's state directory (the "
            f"--state-dir of grassd run, or the config's state_dir), or leave --state-dir out",
            param_hint="'--state-dir'")
    if state_dir is not None:  # as root: its owner, before reading it
        return config_as_state_owner(config_path, str(state_dir), "studio")
    return resolve_config(config_path)


def _check_readable(**files: Path | None) -> None:
    """Each file given (by its option's name) is readable by the user the studio runs as (a
    root's file may not be, once the studio runs as the state directory's owner)."""
    from grassd.sim.path_trust import owner_name

    for option, path in files.items():
        if path is not None and not os.access(path, os.R_OK):
            raise click.BadParameter(f"{path}: not readable by {owner_name(os.geteuid())}, "
                                     f"the user the studio runs as; put it where that user "
                                     f"can read it", param_hint=f"'--{option}'")


def _light_sources(cfg: Config, hdri: Path | None, state_dir: Path | None
                   ) -> tuple[list[LightSource], list[int] | None]:
    """The studio's lights, ``--hdri`` first then the state directory's archived bundles (else
    the embedded default site), and the daemon's active table (256,) [um] where the state
    directory has one."""
    from grassd.daemon.studio.inputs import StudioInputError
    from grassd.daemon.studio.lights import LightSource, archived_sources
    from grassd.sim.hdri import default_site_hdri

    sources = []
    if hdri is not None:
        file_source = LightSource(name="file", label=f"file: {hdri.name}", path=hdri)
        try:
            file_source.check()
        except StudioInputError as exc:
            raise click.BadParameter(str(exc), param_hint="'--hdri'") from None
        sources.append(file_source)
    active = None
    if state_dir is not None:
        try:
            bundles = archived_sources(cfg.state_dir, cfg)
        except StudioInputError as exc:
            raise click.BadParameter(str(exc), param_hint="'--state-dir'") from None
        if not bundles:
            lit = f"{hdri.name} only" if hdri is not None else "the embedded default site"
            click.echo(f"grassd studio: {state_dir} holds no usable archived bundle; the light "
                       f"is {lit}", err=True)
        sources += bundles
        active = _active_table(cfg.state_dir)
    if not sources:
        sources.append(LightSource(name="default-site", label="embedded default site",
                                   path=default_site_hdri()))
    return sources, active


async def _serve(args: StudioArgs, host: str, port: int, token: str | None, said: str
                 ) -> None:
    """Serve the studio until it is stopped, printing its URL (with ``token``) once it
    listens, then what it ``said`` it shows."""
    from grassd.daemon.studio.server import serve

    ready = asyncio.get_running_loop().create_future()
    server = asyncio.create_task(serve(args, host, port, token, ready))
    done, _ = await asyncio.wait({server, ready}, return_when=asyncio.FIRST_COMPLETED)
    if server in done:
        server.result()  # raises the bind error
    h, p = ready.result()
    every = h in ("0.0.0.0", "::")  # no machine can open that: this one's name instead
    shown = socket.gethostname() if every else f"[{h}]" if ":" in h else h
    url = f"http://{shown}:{p}/" + (f"?token={token}" if token else "")
    click.echo(f"grassd studio: {url}", err=False)
    if every:
        click.echo(f"  listening on every address of this machine ({h}): from another "
                   f"machine, this name or any of its addresses, with port and token",
                   err=True)
    click.echo(f"  {said}", err=True)
    await server
