"""How each pixel of a display departs from the model pixel: a length offset and two gains.

One type for both sides of a measurement: the hidden truth a simulated display carries
(``--sim-display-variation FILE``) and what ``grassd measure`` estimates from photos.

* ``length_offset_mm``: the grass the pixel really shows minus the length it was commanded
  (its motor's own zero, the grass sitting differently in the slits), in mm;
* ``green_gain`` / ``yellow_gain``: factors on the pixel's *linear* green and yellow albedos
  (tuft density, fading); 1 = the model pixel.

The file is TOML, one ``[[pixel]]`` table per pixel that departs (pixels not listed are the
model pixel)::

    [[pixel]]
    index = 5                 # row-major pixel index, 0 .. rows * cols - 1
    length_offset_mm = 0.8
    green_gain = 0.9
    yellow_gain = 1.1
"""

from __future__ import annotations

import tomllib
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TypedDict

import numpy as np
import tomli_w
from numpy.typing import NDArray

from grassd.daemon.core.config import schema
from grassd.daemon.core.errors import ConfigError

#: Bounds a variation file's values must keep (a gain outside is a broken pixel, not a
#: variation; an offset beyond a few mm is a motor out of its range).
OFFSET_LIMIT_MM: float = 5.0
GAIN_RANGE: tuple[float, float] = (0.25, 4.0)


class PixelVariation(TypedDict):
    """One pixel's departure as a variation file's ``[[pixel]]`` table, the display
    correction's file and a measurement's report hold it (module docstring)."""

    index: int
    length_offset_mm: float
    green_gain: float
    yellow_gain: float


class VariationFileError(ConfigError):
    """A display variation file is malformed (its message names the key and line)."""


@dataclass(frozen=True, eq=False)
class DisplayVariation:
    """Per-pixel departures from the model pixel, arrays of shape (N,), row-major pixels."""

    length_offset_mm: NDArray[np.float64]
    green_gain: NDArray[np.float64]
    yellow_gain: NDArray[np.float64]

    @classmethod
    def none(cls, n_pixels: int) -> DisplayVariation:
        """Every pixel the model pixel."""
        return cls(np.zeros(n_pixels), np.ones(n_pixels), np.ones(n_pixels))

    @property
    def n_pixels(self) -> int:
        """Number of pixels N."""
        return len(self.length_offset_mm)

    def albedos(self, green_linear: NDArray[np.float64], yellow_linear: NDArray[np.float64]
                ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """(N, 3) linear green and yellow albedos of every pixel (clipped to 1)."""
        g = np.clip(self.green_gain[:, None] * np.asarray(green_linear)[None, :], 0.0, 1.0)
        y = np.clip(self.yellow_gain[:, None] * np.asarray(yellow_linear)[None, :], 0.0, 1.0)
        return g, y

    def pixels(self) -> list[PixelVariation]:
        """One dict per pixel (``index``, ``length_offset_mm``, ``green_gain``,
        ``yellow_gain``), as the file and ``grassd measure --json`` write them."""
        return [{"index": i, "length_offset_mm": float(self.length_offset_mm[i]),
                 "green_gain": float(self.green_gain[i]),
                 "yellow_gain": float(self.yellow_gain[i])} for i in range(self.n_pixels)]

    def to_toml(self) -> str:
        """The variation as a file's TOML text, one ``[[pixel]]`` table per pixel."""
        return "\n".join("[[pixel]]\n" + tomli_w.dumps(p) for p in self.pixels())

    @classmethod
    def from_pixels(cls, rows: Sequence[PixelVariation], n_pixels: int) -> DisplayVariation:
        """From dicts as :meth:`pixels` writes them (values already checked)."""
        v = cls.none(n_pixels)
        for r in rows:
            i = int(r["index"])
            v.length_offset_mm[i] = float(r["length_offset_mm"])
            v.green_gain[i] = float(r["green_gain"])
            v.yellow_gain[i] = float(r["yellow_gain"])
        return v


def load_variation(path: str | Path, n_pixels: int) -> DisplayVariation:
    """Read a variation file (module docstring) for a display of ``n_pixels`` pixels.

    Raises :class:`VariationFileError` naming the key and line of anything wrong: an unknown
    key, an index outside the display or listed twice, an offset beyond +-5 mm, a gain
    outside 0.25..4."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
        data = tomllib.loads(text)
    except OSError as exc:
        raise VariationFileError(f"cannot read the display variation file: {exc.strerror}",
                                 path=str(p)) from None
    except (UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
        raise VariationFileError(f"not valid TOML: {exc}", path=str(p)) from None
    ctx = schema.Context(text, str(p), p.parent, error=VariationFileError)
    top = schema.table(ctx, (), data, {"pixel": schema.Field(list, [])})
    F = schema.Field
    lo, hi = GAIN_RANGE
    fields = {"index": F(int, check=schema.between(0, n_pixels - 1, "")),
              "length_offset_mm": F(float, 0.0, schema.between(-OFFSET_LIMIT_MM,
                                                               OFFSET_LIMIT_MM, " mm")),
              "green_gain": F(float, 1.0, schema.between(lo, hi)),
              "yellow_gain": F(float, 1.0, schema.between(lo, hi))}
    rows: list[PixelVariation] = []
    seen = set()
    for k, raw in enumerate(top["pixel"]):
        row = schema.table(ctx, ("pixel", k), raw, fields)
        if row["index"] in seen:
            raise ctx.error(("pixel", k, "index"), f"pixel {row['index']} is listed twice")
        seen.add(row["index"])
        rows.append(PixelVariation(index=row["index"], length_offset_mm=row["length_offset_mm"],
                                   green_gain=row["green_gain"], yellow_gain=row["yellow_gain"]))
    return DisplayVariation.from_pixels(rows, n_pixels)
