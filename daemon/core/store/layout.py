"""The state directory's layout: every file and directory the daemon keeps there, named once.

::

    <state_dir>/
        state.db              history of runs, tables, pushes and the ingest journal (SQLite)
        grassd.lock           held by the one daemon (or command) that owns the directory
        camera.lock           held by whoever drives the capture station's camera
        processing/<id>/      a claimed bundle while its run lasts
        archive/<id>/         bundles done with (applied, or superseded)
        rejected/<id>/        bundles refused, each with its reason.txt
        reports/run-NNNNNN.json, .png   a run's report and plot
        reports/index.html    the operator's status page
        measure/setup.json    the measuring camera's colour chain (checker photographed at set-up)
        measure/correction.json   the display's per-pixel correction the tables include
        measure/YYYYmmddTHHMMSSZ.json, .html, photos/   one measurement: report and its photos

The inbox is configured (``[light] inbox``) and may lie elsewhere. Run reports are named by
:func:`report_stem` and read back (retention) by :func:`report_run_id`.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass
from pathlib import Path

STATE_DB = "state.db"
LOCK_NAME = "grassd.lock"
CAMERA_LOCK = "camera.lock"
PAGE_NAME = "index.html"
MEASURE_SETUP = "setup.json"
CORRECTION = "correction.json"

_REPORT_RE = re.compile(r"^run-(\d+)\.(json|png)$")


def report_stem(run_id: int) -> str:
    """A run's report file name without its suffix (``.json`` report, ``.png`` plot).

    >>> report_stem(42)
    'run-000042'
    """
    return f"run-{run_id:06d}"


def report_run_id(file_name: str) -> int | None:
    """The run id of a report or plot file name (``run-000042.json`` -> 42), None for any
    other name.

    >>> report_run_id("run-000042.png"), report_run_id("index.html")
    (42, None)
    """
    m = _REPORT_RE.match(file_name)
    return int(m.group(1)) if m else None


@dataclass(frozen=True)
class StateLayout:
    """The paths of a state directory ``root`` (see the module docstring). Nothing is created
    here: the owner of each path makes it when it first writes."""

    root: Path

    def __init__(self, root: str | os.PathLike[str]) -> None:
        object.__setattr__(self, "root", Path(root))

    @property
    def db(self) -> Path:
        """The history database."""
        return self.root / STATE_DB

    @property
    def processing(self) -> Path:
        """Claimed bundles."""
        return self.root / "processing"

    @property
    def archive(self) -> Path:
        """Bundles done with."""
        return self.root / "archive"

    @property
    def rejected(self) -> Path:
        """Refused bundles."""
        return self.root / "rejected"

    @property
    def reports(self) -> Path:
        """Run reports and the status page."""
        return self.root / "reports"

    @property
    def status_page(self) -> Path:
        """The operator's status page."""
        return self.reports / PAGE_NAME

    def report_base(self, run_id: int) -> Path:
        """A run's report path without its suffix (``.json`` report, ``.png`` plot)."""
        return self.reports / report_stem(run_id)

    @property
    def measure(self) -> Path:
        """Measurements of the display (``grassd measure``): reports, photos, correction."""
        return self.root / "measure"

    @property
    def correction(self) -> Path:
        """The display's per-pixel correction that every run's tables include."""
        return self.measure / CORRECTION

    @property
    def measure_setup(self) -> Path:
        """The measuring camera's colour chain from the checker photographed at set-up."""
        return self.measure / MEASURE_SETUP

    def measurement_reports(self) -> list[Path]:
        """Every measurement's JSON report, oldest first (named by their UTC start time)."""
        return sorted(p for p in self.measure.glob("*T*Z.json") if p.is_file())
