"""Benchmarks: ``make bench`` (= ``python -m bench``) runs every ``bench_*.py`` module's
``main()``; each prints its numbers and asserts nothing (speed is reported, not tested).

Two settings every benchmark reads from the environment:

- ``GRASSD_BENCH_HDRI_DIR``: the folder of the shared CC0 panoramas (default ``../shared/hdri``
  beside the checkout, as CI has it); a benchmark that needs them and finds none says so and
  skips.
- ``GRASSD_BENCH_ARCH``: the Taichi arch of the benchmarks that take one (``cpu``, the default,
  or ``gpu``: ``bench/device_check.sh`` on a machine with a GPU).
"""

from __future__ import annotations

import os
from pathlib import Path

HDRI_DIR: Path = Path(os.environ.get(
    "GRASSD_BENCH_HDRI_DIR", Path(__file__).resolve().parents[1].parent / "shared" / "hdri"))
#: The panorama of the benchmarks that time one light (the studio, the splay, the display).
COURTYARD: Path = HDRI_DIR / "courtyard.exr"
ARCH: str = os.environ.get("GRASSD_BENCH_ARCH", "cpu")
