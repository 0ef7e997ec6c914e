"""A sweep's settings: :class:`SweepSpec` (shared by every task) and the run's defaults.

Kept apart from :mod:`grassd.daemon.offline.sweep`, which runs sweeps, so that the ``grassd
sweep`` command can show and use these defaults without loading the offline package (``grassd
run`` builds every sub-command and must not load it).
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, fields

from grassd.sim.scene import RenderSettings

#: Local worker processes of a sweep.
SWEEP_WORKERS = 2
#: Extra attempts of a failing task on a Dask cluster.
SWEEP_RETRIES = 2
#: Below this OGCD range (dE00) a condition counts as one where the display loses contrast.
DEFAULT_CONTRAST_THRESHOLD = 5.0


@dataclass(frozen=True)
class SweepSpec:
    """Settings shared by every task of a sweep.

    Lengths [mm]; ``lux`` [lx]: ambient lux when no time of day is given; site ``latitude`` /
    ``longitude`` [deg], ``date`` (YYYY-MM-DD) and ``timezone`` (IANA) for times of day;
    ``night_lux`` [lx] of sky light when the sun is below 3 deg; display ``rows`` x ``cols``
    (the centre pixel is measured); Monte Carlo ``samples``, ``replicates``, ``bounces``,
    ``light_samples``, ``target_stderr`` [dE00] (None: fixed replicates); ``seed`` mixes into
    every task's seed.
    """

    lengths_mm: tuple[float, ...]
    samples: int = 1024
    replicates: int = RenderSettings.replicates
    bounces: int = RenderSettings.max_bounces
    light_samples: int = RenderSettings.light_samples
    target_stderr: float | None = None
    seed: int = 0
    lux: float = 20000.0
    night_lux: float = 50.0
    latitude: float | None = None
    longitude: float | None = None
    date: str | None = None
    timezone: str = "UTC"
    rows: int = 1
    cols: int = 1

    def to_json(self) -> str:
        """Canonical JSON (sorted keys) used for task keys and the output's metadata."""
        return json.dumps(asdict(self), sort_keys=True)


def spec_default(name: str) -> float | str | None:
    """The default of :class:`SweepSpec` field ``name`` (a number, a name or None;
    ``KeyError`` for a field without one).

    >>> spec_default("lux")
    20000.0
    """
    return {f.name: f.default for f in fields(SweepSpec)
            if f.default is None or isinstance(f.default, int | float | str)}[name]
