"""Reference colour checkers: patch names and CIELAB (D50) values of 24-patch charts.

Three sources, one type (:class:`ReferenceChart`):

* ColorChecker Classic (X-Rite, formulation after November 2014) from colour-science's
  ``CCS_COLOURCHECKERS`` (xyY under ICC D50, converted here to CIELAB with the D50 white).
* Datacolor SpyderCheckr 24 (the chart used by the paper). colour-science does not ship it; the
  D50 CIELAB values below are Datacolor's published figures as tabulated by darktable,
  ``src/common/colorchecker.h``, target ``spyder_24_v2`` ("Datacolor SpyderCheckr 24 after
  2018"), typed in here. Patch order is reading order (rows top to bottom, columns left to right)
  in darktable's guide frame: rows D, C, B, A, the A row holding the greys A1 (white) .. A6.
* Any other chart from a CSV file: ``name,L,a,b`` per line (CIELAB, D50 white), ``#`` comments.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from grassd.calib.colour_spaces import WHITE_D50_XY, lab_to_prophoto, xyz_to_lab
from grassd.calib.errors import ChartError, UnknownMethodError

#: Patches of the charts this package handles, arranged as (rows, columns).
CHART_GRID: tuple[int, int] = (4, 6)


@dataclass(frozen=True, eq=False)
class ReferenceChart:
    """A 24-patch reference chart: names and CIELAB (D50 white) values in reading order.

    Attributes:
        name: human-readable chart name.
        patch_names: 24 patch names, row-major from the top-left patch.
        lab: (24, 3) CIELAB values under D50 (L* in 0..100).
        source: where the numbers come from.
    """

    name: str
    patch_names: tuple[str, ...]
    lab: NDArray[np.float64]
    source: str

    def prophoto(self) -> NDArray[np.float64]:
        """(24, 3) ProPhoto linear RGB of the patches (D50, Y of white = 1)."""
        return lab_to_prophoto(self.lab)

    def grey_index(self) -> int:
        """Index of the neutral patch closest to an 18 % grey (L* = 49.5)."""
        chroma = np.hypot(self.lab[:, 1], self.lab[:, 2])
        score = np.abs(self.lab[:, 0] - 49.5) + np.where(chroma > 5.0, 1e3, 0.0)
        return int(np.argmin(score))


def _make(name: str, names: list[str], lab: NDArray[np.float64], source: str) -> ReferenceChart:
    lab = np.array(lab, dtype=np.float64)
    lab.setflags(write=False)
    return ReferenceChart(name=name, patch_names=tuple(names), lab=lab, source=source)


def colorchecker_classic() -> ReferenceChart:
    """X-Rite ColorChecker Classic (after November 2014), from colour-science (D50 CIELAB)."""
    import colour  # on first use: see grassd.calib.colour_spaces

    cc = colour.CCS_COLOURCHECKERS["ColorChecker24 - After November 2014"]
    xyy = np.array(list(cc.data.values()), dtype=np.float64)
    if not np.allclose(cc.illuminant, WHITE_D50_XY, atol=1e-5):  # pragma: no cover - data guard
        raise ChartError(f"colour-science's ColorChecker illuminant {cc.illuminant} is not D50")
    lab = xyz_to_lab(colour.xyY_to_XYZ(xyy))
    return _make(
        "ColorChecker Classic (after Nov 2014)",
        list(cc.data.keys()),
        lab,
        "colour-science CCS_COLOURCHECKERS['ColorChecker24 - After November 2014'] (xyY, D50)",
    )


# darktable src/common/colorchecker.h, spyder_24_v2, reordered to reading order (D, C, B, A rows).
_SPYDER24 = (
    ("D1", 70.19, -31.85, 1.98), ("D2", 54.38, 8.84, -25.71), ("D3", 42.03, -15.78, 22.93),
    ("D4", 48.82, -5.11, -23.08), ("D5", 65.10, 18.14, 18.68), ("D6", 36.13, 14.15, 15.78),
    ("C1", 60.94, 38.21, 61.31), ("C2", 37.80, 7.30, -43.04), ("C3", 49.81, 48.50, 15.76),
    ("C4", 28.88, 19.36, -24.48), ("C5", 72.45, -23.57, 60.47), ("C6", 71.65, 23.74, 72.28),
    ("B1", 47.12, -32.50, -28.75), ("B2", 50.49, 53.45, -13.55), ("B3", 83.61, 3.36, 87.02),
    ("B4", 41.05, 60.75, 31.17), ("B5", 54.14, -40.80, 34.75), ("B6", 24.75, 13.78, -49.48),
    ("A1", 96.04, 2.16, 2.60), ("A2", 80.44, 1.17, 2.05), ("A3", 65.52, 0.69, 1.86),
    ("A4", 49.62, 0.58, 1.56), ("A5", 33.55, 0.35, 1.40), ("A6", 16.91, 1.43, -0.81),
)  # fmt: skip


def spyder_checkr_24() -> ReferenceChart:
    """Datacolor SpyderCheckr 24 (after 2018), D50 CIELAB as tabulated by darktable."""
    return _make(
        "Datacolor SpyderCheckr 24 (after 2018)",
        [p[0] for p in _SPYDER24],
        np.array([p[1:] for p in _SPYDER24]),
        "Datacolor published D50 Lab, as tabulated in darktable src/common/colorchecker.h "
        "(spyder_24_v2)",
    )


def load_chart(path: str | Path, name: str | None = None) -> ReferenceChart:
    """Read a 24-patch chart from a CSV file with rows ``name,L,a,b`` (CIELAB, D50 white).

    Lines starting with ``#`` and a header row whose L column is not numeric are skipped.
    """
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except OSError as exc:
        raise ChartError(f"cannot read chart file {p}: {exc.strerror or exc}") from exc
    names: list[str] = []
    values: list[list[float]] = []
    for lineno, row in enumerate(csv.reader(text.splitlines()), start=1):
        if not row or not "".join(row).strip() or row[0].lstrip().startswith("#"):
            continue
        if len(row) != 4:
            raise ChartError(f"{p}:{lineno}: expected 4 columns name,L,a,b; got {len(row)}")
        try:
            lab = [float(v) for v in row[1:]]
        except ValueError as exc:
            if not values and not names:  # header line
                continue
            raise ChartError(f"{p}:{lineno}: L, a, b must be numbers ({exc})") from exc
        if not np.all(np.isfinite(lab)) or not 0.0 <= lab[0] <= 100.0:
            raise ChartError(f"{p}:{lineno}: L* must be in 0..100 and a*, b* finite; got {lab}")
        names.append(row[0].strip())
        values.append(lab)
    rows, cols = CHART_GRID
    if len(values) != rows * cols:
        raise ChartError(
            f"{p}: a chart needs {rows * cols} patches (name,L,a,b rows); found {len(values)}"
        )
    return _make(name or p.stem, names, np.array(values), f"file {p}")


#: Built-in chart name -> factory.
CHARTS = {
    "colorchecker-classic": colorchecker_classic,
    "spydercheckr-24": spyder_checkr_24,
}


def chart_key(name: str | Path) -> str:
    """``name`` as :data:`CHARTS` keys it (lower case, ``-`` for spaces and underscores).

    >>> chart_key("SpyderCheckr 24")
    'spydercheckr-24'
    """
    return str(name).lower().replace(" ", "-").replace("_", "-")


def get_chart(name_or_path: str | Path) -> ReferenceChart:
    """A built-in chart by name (see :data:`CHARTS`, :func:`chart_key`) or a chart CSV file by
    path."""
    key = chart_key(name_or_path)
    if key in CHARTS:
        return CHARTS[key]()
    p = Path(name_or_path)
    if p.suffix.lower() == ".csv" or p.exists():
        return load_chart(p)
    raise UnknownMethodError(
        f"unknown chart {name_or_path!r}; use one of {', '.join(CHARTS)} or a path to a CSV file "
        "with rows name,L,a,b (D50)"
    )
