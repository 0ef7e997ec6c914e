"""Click parameter types shared by the ``grassd`` sub-commands."""

from __future__ import annotations

import click

from grassd.sim.scene import MAX_REPLICATES, RenderSettings

#: Type of every ``--replicates`` option: at least 2 (their spread is the standard error), at
#: most what one render takes.
REPLICATES = click.IntRange(2, MAX_REPLICATES)

#: The renderer's defaults, which every sub-command's Monte Carlo options show and use.
RENDER_DEFAULTS = RenderSettings()
