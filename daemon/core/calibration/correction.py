"""The display's per-pixel correction, which every run's tables include once it is measured.

``grassd measure`` finds each pixel's departure from the model pixel (a
:class:`~grassd.daemon.core.calibration.variation.DisplayVariation`) and, through the pixel models
of the configured viewers, the length to command each pixel so that it looks like the model pixel at
each length (:func:`grassd.daemon.measure.pixel_model.corrected_commands`). That mapping, per pixel,
is the :class:`DisplayCorrection`: a calibration run builds its tables for the model pixel as before
(simulation, OGCD, inversion, closed loop) and then reads each pixel's row through its mapping
(:meth:`DisplayCorrection.apply`), so every controller gets per-pixel tables.

It is kept in the state directory (``measure/correction.json``, written atomically once a
measurement is accepted) and applies to every later run, whatever its light, until the next
measurement replaces it. A correction made for another display size is ignored with a warning.

Units: lengths mm (tables micrometres, uint16).
"""

from __future__ import annotations

import json
import logging
from dataclasses import dataclass, replace
from enum import Enum
from pathlib import Path
from typing import TYPE_CHECKING, Final, TypedDict

import numpy as np
from numpy.typing import NDArray

from grassd.daemon.core.calibration.variation import DisplayVariation, PixelVariation

if TYPE_CHECKING:
    from grassd.daemon.core.calibration.result import CalibrationResult
    from grassd.daemon.core.config.settings import Config

log = logging.getLogger(__name__)

class Saved(Enum):
    """The type of :data:`SAVED`."""

    SAVED = "the correction the state directory holds"


#: ``Calibrator.run(correction=SAVED)``: the correction the state directory holds.
SAVED: Final = Saved.SAVED


class CorrectionJson(TypedDict):
    """A :class:`DisplayCorrection` as ``correction.json`` holds it (lengths mm)."""

    measurement: str
    shape: list[int]
    pixels: list[PixelVariation]
    nominal_mm: list[float]
    commands_mm: list[list[float]]


@dataclass(frozen=True, eq=False)
class DisplayCorrection:
    """Per-pixel correction (module docstring): ``variation`` (N pixels), the commands
    ``commands_mm`` (N, L) that make each pixel look like the model pixel at ``nominal_mm`` (L,),
    the display ``shape`` (rows, cols) and the ``measurement`` that made it (its id)."""

    variation: DisplayVariation
    nominal_mm: NDArray[np.float64]
    commands_mm: NDArray[np.float64]
    shape: tuple[int, int]
    measurement: str

    def command_um(self, pixels: NDArray, nominal_um: NDArray) -> NDArray[np.uint16]:
        """(n, 256) tables of display ``pixels`` (n,) whose model-pixel tables are
        ``nominal_um`` ((n, 256) or (256,), micrometres)."""
        nominal = np.broadcast_to(np.asarray(nominal_um, dtype=np.float64) / 1000.0,
                                  (len(pixels), np.shape(nominal_um)[-1]))
        out = np.stack([np.interp(nominal[k], self.nominal_mm, self.commands_mm[p])
                        for k, p in enumerate(np.asarray(pixels))])
        return np.rint(out * 1000.0).astype(np.uint16)

    def apply(self, cfg: Config, result: CalibrationResult) -> CalibrationResult:
        """``result`` with every controller's table per pixel and
        corrected: each pixel's row (its controller's own table, or the display-wide one) read
        through that pixel's mapping."""
        from grassd.daemon.core.calibration.display_model import controller_pixels

        n = self.variation.n_pixels
        tables = {}
        for c, pix in zip(cfg.controllers, controller_pixels(cfg.controllers, n), strict=True):
            own = result.controller_tables.get(c.name)
            tables[c.name] = self.command_um(pix, own if own is not None else result.table_um)
        return replace(result, controller_tables=tables, correction=self.measurement)

    def to_json(self) -> CorrectionJson:
        """The correction as ``correction.json`` holds it."""
        return {"measurement": self.measurement, "shape": list(self.shape),
                "pixels": self.variation.pixels(), "nominal_mm": self.nominal_mm.tolist(),
                "commands_mm": np.round(self.commands_mm, 4).tolist()}

    @classmethod
    def from_json(cls, d: CorrectionJson) -> DisplayCorrection:
        """Read :meth:`to_json`'s form back."""
        shape = (int(d["shape"][0]), int(d["shape"][1]))
        n = shape[0] * shape[1]
        commands = np.asarray(d["commands_mm"], dtype=np.float64)
        nominal = np.asarray(d["nominal_mm"], dtype=np.float64)
        if commands.shape != (n, len(nominal)) or np.any(np.diff(nominal) <= 0):
            raise ValueError(f"commands of shape {commands.shape} for {n} pixels and "
                             f"{len(nominal)} increasing nominal lengths")
        return cls(DisplayVariation.from_pixels(d["pixels"], n), nominal, commands, shape,
                   str(d["measurement"]))


def load_correction(path: Path, shape: tuple[int, int]) -> DisplayCorrection | None:
    """The correction at ``path`` for a display of ``shape`` (rows, cols); None when there is
    none, and None with a warning when it is unreadable or made for another display."""
    try:
        corr = DisplayCorrection.from_json(json.loads(path.read_text(encoding="utf-8")))
    except FileNotFoundError:
        return None
    except (OSError, ValueError, KeyError, TypeError, IndexError) as exc:
        log.warning("display correction %s unusable (%s); tables are not corrected: run "
                    "grassd measure --now", path, exc)
        return None
    if corr.shape != tuple(shape):
        log.warning("display correction %s is for a %d x %d display, this one is %d x %d; "
                    "ignored until the display is measured again", path, *corr.shape, *shape)
        return None
    return corr


def saved_correction(cfg: Config) -> DisplayCorrection | None:
    """The correction in ``cfg``'s state directory for its display, or None."""
    from grassd.daemon.core.store.layout import StateLayout

    d = cfg.display
    return load_correction(StateLayout(cfg.state_dir).correction, (d.rows, d.cols))


def with_correction(cfg: Config, result: CalibrationResult,
                    correction: DisplayCorrection | Saved | None) -> CalibrationResult:
    """``result`` with the display's per-pixel ``correction`` applied
    (:data:`SAVED`: the one in ``cfg``'s state directory, if any; None: none)."""
    if correction is SAVED:
        correction = saved_correction(cfg)
    return result if correction is None else correction.apply(cfg, result)
