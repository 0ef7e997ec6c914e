"""``grassd bundles list`` and ``grassd bundles retry``: quarantined bundles.

A bundle whose processing was interrupted ``max_attempts`` times ends in ``rejected/`` as
"abandoned" (see :mod:`grassd.daemon.core.store.quarantine`). ``list`` shows them (``grassd status``
too); ``retry NAME`` puts one back into the inbox with a fresh attempt count, through the
running daemon's control socket (it does it between two passes of its main loop), or, when no
daemon runs, itself while holding the state directory's lock.
"""

from __future__ import annotations

import json

import click

from grassd.daemon.cli.run import _fmt_time
from grassd.daemon.core.config.settings import CONFIG_OPTION_HELP
from grassd.daemon.core.safe_text import one_line


@click.group("bundles")
def bundles() -> None:
    """Bundles quarantined after repeated interrupted attempts: list them, retry one."""


@bundles.command("list")
@click.option("--config", "config_path", type=click.Path(dir_okay=False),
              help=CONFIG_OPTION_HELP)
@click.option("--state-dir", type=click.Path(file_okay=False), help="override the state directory")
@click.option("--json", "as_json", is_flag=True, help="print JSON")
def list_cmd(config_path: str | None, state_dir: str | None, as_json: bool) -> None:
    """Quarantined bundles: id, upload name, attempts, since when (read from the state
    database; works with or without a running daemon)."""
    from grassd.daemon.core.errors import HistoryError
    from grassd.daemon.core.runtime.state_owner import config_as_state_owner
    from grassd.daemon.core.store.history import History
    from grassd.daemon.core.store.layout import StateLayout
    from grassd.daemon.core.store.quarantine import quarantined

    cfg = config_as_state_owner(config_path, state_dir, "bundles list")
    db = StateLayout(cfg.state_dir).db
    if not db.exists():
        raise HistoryError(f"no state database at {db}")
    with History(db) as h:
        found = quarantined(h, cfg.light.inbox, cfg.state_dir)
    if as_json:
        click.echo(json.dumps([q.as_dict() for q in found], indent=2))
        return
    if not found:
        click.echo("no quarantined bundles")
    for q in found:
        click.echo(one_line(f"{q.bundle}  {q.name}  {q.attempts} attempts, since "
                            f"{_fmt_time(q.since)}: {q.reason}", None))  # names escaped


@bundles.command("retry")
@click.argument("bundle")
@click.option("--config", "config_path", type=click.Path(dir_okay=False),
              help=CONFIG_OPTION_HELP)
@click.option("--state-dir", type=click.Path(file_okay=False), help="override the state directory")
def retry_cmd(bundle: str, config_path: str | None, state_dir: str | None) -> None:
    """Put quarantined BUNDLE (its id, or its upload name) back into the inbox to run again."""
    from grassd.daemon.core.errors import DaemonNotRunning
    from grassd.daemon.core.runtime.control import request
    from grassd.daemon.core.runtime.state_owner import config_as_state_owner
    from grassd.daemon.core.runtime.statelock import StateLock
    from grassd.daemon.core.store.history import History
    from grassd.daemon.core.store.ingest import Inbox
    from grassd.daemon.core.store.layout import StateLayout
    from grassd.daemon.core.store.quarantine import BundleRetryError, retry_request

    cfg = config_as_state_owner(config_path, state_dir, "bundles retry")
    try:
        out = request(cfg.control_socket, {"cmd": "bundles_retry", "bundle": bundle},
                      timeout_s=3600)["retry"]
        how = "the daemon put"
    except DaemonNotRunning:
        with StateLock(cfg.state_dir, "grassd bundles retry"), \
                History(StateLayout(cfg.state_dir).db) as h:
            done = retry_request(Inbox(cfg.light.inbox, cfg.state_dir, h,
                                       tz=cfg.site.timezone, limits=cfg.light.limits),
                                 bundle)
        if done.done is None:
            raise BundleRetryError(done.error or "") from None
        out = done.done
        how = "put"
    click.echo(f"{how} {out['bundle']} back into the inbox as {out['inbox_path']} (it had "
               f"{out['attempts']} interrupted attempts); it runs as a new upload")
