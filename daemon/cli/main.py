"""The ``grassd`` command line (click).

Sub-commands live in the other modules of this package (``daemon/cli/*.py``) and are added to
:func:`main` below. User errors (bad input, bad config, unreachable hardware) print one line and
exit with code 2.
"""

from __future__ import annotations

import sys

import click

from grassd import __version__
from grassd.daemon.cli.bundles import bundles
from grassd.daemon.cli.capture import camera_group, capture_cmd
from grassd.daemon.cli.controllers import controllers
from grassd.daemon.cli.demo import demo
from grassd.daemon.cli.fit import fit
from grassd.daemon.cli.run import calibrate_cmd, check_config, history_cmd, run_cmd, status_cmd
from grassd.daemon.cli.simulate import simulate
from grassd.daemon.cli.studio import studio
from grassd.daemon.cli.sweep import sweep
from grassd.daemon.cli.validate import experiment, validate
from grassd.daemon.errors import USER_ERRORS


class _Group(click.Group):
    """Top-level group that turns user errors into one line and exit code 2."""

    def invoke(self, ctx: click.Context):  # click API
        try:
            return super().invoke(ctx)
        except USER_ERRORS as exc:
            click.echo(f"grassd: error: {exc}", err=True)
            sys.exit(2)


@click.group(cls=_Group, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="grassd")
def main() -> None:
    """grassd keeps a grass display's colours true as the light around it changes."""


for _command in (demo, check_config, run_cmd, status_cmd, history_cmd, calibrate_cmd, bundles,
                 controllers, simulate, validate, fit, experiment, sweep, studio, capture_cmd,
                 camera_group):
    main.add_command(_command)
