"""``grassd fit``'s Monte Carlo settings (:class:`FitSettings`).

Kept apart from :mod:`grassd.daemon.offline.fit`, which fits, so that the ``grassd fit``
command can show and use these defaults without loading the offline package (``grassd run``
builds every sub-command and must not load it).
"""

from __future__ import annotations

from dataclasses import dataclass

from grassd.sim.scene import RenderSettings


@dataclass(frozen=True)
class FitSettings:
    """Monte Carlo settings of the fit: ``samples`` camera paths per length per replicate,
    ``replicates`` per layout, ``layouts`` random tuft layouts averaged (seeds from the start
    pixel's ``layout_seed`` on), ``seed`` of the paths, ``max_bounces`` (the renderer's
    default: Russian roulette alone; up to 3 the recorded polynomial is exact at any albedo,
    deeper paths are recorded to :data:`grassd.sim.albedo_terms.TERM_DEGREE` with a tail term),
    ``lab_floor``: the photos' own noise per CIELAB component, added to the layout spread and
    the Monte Carlo error in the residuals' weights."""

    samples: int = 1024
    replicates: int = 4
    layouts: int = 6
    seed: int = 0
    max_bounces: int = RenderSettings.max_bounces
    lab_floor: float = 0.25

    def __post_init__(self) -> None:
        if self.layouts < 2:
            raise ValueError("fit needs at least 2 layouts: their spread is part of the error")
        if self.replicates < 1 or self.samples < 16:
            raise ValueError("fit needs at least 1 replicate of 16 samples per layout")
