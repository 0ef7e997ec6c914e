"""The ``grassd`` command line (click).

Sub-commands live in this package (``daemon/cli/*.py``) and in the ``cli`` module of each
feature and tool. :func:`main` names them in :data:`COMMANDS` and imports a module only when
one of its commands runs (or shows its own help), so ``grassd --help`` and the light commands
start fast (the import-graph test checks which modules they load). User errors (bad input,
bad config, unreachable hardware) print one line and exit with code 2.
"""

from __future__ import annotations

import sys

import click

from grassd import __version__
from grassd.daemon.cli.lazy import LazyCommand, LazyGroup
from grassd.daemon.core.errors import USER_ERRORS

_CLI = "grassd.daemon.cli."
#: each feature's and tool's command group, in its own folder
_CAPTURE, _MEASURE, _SHOW = ("grassd.daemon.capture.cli", "grassd.daemon.measure.cli",
                             "grassd.daemon.content.cli")
_STUDIO, _OFFLINE = "grassd.daemon.studio.cli", "grassd.daemon.offline."

#: Every sub-command of ``grassd``: its name -> where it lives and the first paragraph of its
#: help (tests/daemon/cli/test_lazy_commands.py checks each against the loaded command).
COMMANDS: dict[str, LazyCommand] = {
    "bundles": LazyCommand(_CLI + "bundles", "bundles", "Bundles quarantined after repeated "
                           "interrupted attempts: list them, retry one."),
    "calibrate": LazyCommand(_CLI + "run", "calibrate_cmd", "Ask the running daemon for a "
                             "calibration, or run one here when no daemon runs."),
    "camera": LazyCommand(_CAPTURE, "camera_group", "Cameras of the capture station."),
    "capture": LazyCommand(_CAPTURE, "capture_cmd", "Take one bracket with the camera, "
                           "merge it and drop the bundle into the inbox."),
    "check-config": LazyCommand(_CLI + "run", "check_config", "Validate the configuration file "
                                "and print a summary (exit 2 naming key and line if bad)."),
    "controllers": LazyCommand(_CLI + "controllers", "controllers", "Talk to the display's "
                               "controllers over serial, or run simulated ones."),
    "demo": LazyCommand(_CLI + "demo", "demo", "The main job on the embedded default site, "
                        "against simulated hardware."),
    "experiment": LazyCommand(_OFFLINE + "validate_cli", "experiment",
                              "The paper's experiments and virtual captures."),
    "fit": LazyCommand(_OFFLINE + "fit_cli", "fit", "Fit the pixel's materials to the photos "
                       "in CAPTURE (the capture directory that ``grassd validate`` reads): "
                       "albedos, glossy lobe and splay, with standard errors, judged per "
                       "viewpoint against the starting model."),
    "history": LazyCommand(_CLI + "run", "history_cmd", "The run history: inputs, lux, metrics, "
                           "table and per-controller push results."),
    "measure": LazyCommand(_MEASURE, "measure", "Photograph the display under test "
                           "patterns and correct each pixel's tables."),
    "run": LazyCommand(_CLI + "run", "run_cmd", "Run the daemon: watch the inbox, calibrate, "
                       "push tables, serve the control socket."),
    "show": LazyCommand(_SHOW, "show", "Show a picture or animation "
                        "(PNG, JPEG, GIF, APNG) on the display, through the running daemon or "
                        "here when none runs."),
    "simulate": LazyCommand(_OFFLINE + "simulate_cli", "simulate", "Simulate the grass colour "
                            "characteristic (OGCD vs green length) per viewpoint."),
    "status": LazyCommand(_CLI + "run", "status_cmd", "Last runs, each controller's active "
                          "table, and health (asks the daemon if it runs)."),
    "studio": LazyCommand(_STUDIO, "studio", "Serve the interactive studio: move the "
                          "eye, change the light, see the pixel, its colour characteristic, the "
                          "table and a picture on the display. Prints its URL."),
    "sweep": LazyCommand(_OFFLINE + "sweep_cli", "sweep", "Run characteristics over many "
                         "conditions; one tidy SQLite table plus summary plots."),
    "validate": LazyCommand(_OFFLINE + "validate_cli", "validate", "Compare real captures "
                            "(RAW photos + capture.toml in CAPTURE) with the simulation."),
}


class _Group(LazyGroup):
    """Top-level group that turns user errors into one line and exit code 2."""

    def invoke(self, ctx: click.Context):  # click API
        try:
            return super().invoke(ctx)
        except USER_ERRORS as exc:
            click.echo(f"grassd: error: {exc}", err=True)
            sys.exit(2)


@click.group(cls=_Group, lazy=COMMANDS, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="grassd")
def main() -> None:
    """grassd keeps a grass display's colours true as the light around it changes."""
