"""The ``grassd`` command line (click).

Sub-commands live in ``daemon/cli_*.py`` modules and are registered in :data:`SUBCOMMANDS`.
User errors (bad input, bad config, unreachable hardware) print one line and exit with code 2.
"""

from __future__ import annotations

import importlib
import sys

import click

from grassd import __version__
from grassd.daemon.errors import USER_ERRORS

#: "module:attribute" of every sub-command (a click command or group).
SUBCOMMANDS: list[str] = [
    "grassd.daemon.cli_demo:demo",
    "grassd.daemon.cli_run:check_config",
    "grassd.daemon.cli_run:run_cmd",
    "grassd.daemon.cli_run:status_cmd",
    "grassd.daemon.cli_run:history_cmd",
    "grassd.daemon.cli_run:calibrate_cmd",
    "grassd.daemon.cli_controllers:controllers",
    "grassd.daemon.cli_simulate:simulate",
    "grassd.daemon.cli_validate:validate",
    "grassd.daemon.cli_validate:experiment",
    "grassd.daemon.cli_sweep:sweep",
]


class _Group(click.Group):
    """Top-level group that turns user errors into one line and exit code 2."""

    def invoke(self, ctx: click.Context):  # noqa: D401 - click API
        try:
            return super().invoke(ctx)
        except USER_ERRORS as exc:
            click.echo(f"grassd: error: {exc}", err=True)
            sys.exit(2)


@click.group(cls=_Group, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="grassd")
def main() -> None:
    """grassd keeps a grass display's colours true as the light around it changes."""


for _spec in SUBCOMMANDS:
    _mod, _attr = _spec.split(":")
    main.add_command(getattr(importlib.import_module(_mod), _attr))
