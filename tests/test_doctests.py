"""Every ``>>>`` example in the packages' docstrings runs and shows what it claims.

The modules are found by their text (a ``>>>`` line), so a new example is run as soon as it is
written and a module without examples is not imported. Each module's examples run with
numpy's default print options: colour-science sets ``legacy="1.13"`` when imported, which would
make an array's repr depend on what the test process imported before. A module whose text has
``>>>`` lines but whose docstrings give :mod:`doctest` no example fails, so an example cannot
hide in a comment or a nested function and silently stop running.

The modules with examples import only the base install's dependencies (no Taichi, Mitsuba or
systemd), so these run wherever the suite does, in a few seconds.
"""

from __future__ import annotations

import doctest
import importlib
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
#: source folder -> package (pyproject's package-dir)
PACKAGES = {"calib": "grassd.calib", "sim": "grassd.sim", "firmware_proto": "grassd.firmware_proto",
            "rigs": "grassd.rigs", "daemon": "grassd.daemon"}
FLAGS = doctest.NORMALIZE_WHITESPACE


def _modules_with_examples() -> list[str]:
    """Dotted names of the modules whose source has a ``>>>`` line."""
    out = []
    for folder, package in PACKAGES.items():
        for path in sorted((ROOT / folder).rglob("*.py")):
            if not any(line.lstrip().startswith(">>> ") for line in path.read_text().splitlines()):
                continue
            parts = list(path.relative_to(ROOT / folder).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts.pop()
            out.append(".".join([package, *parts]))
    return out


MODULES = _modules_with_examples()


def test_the_examples_are_found():
    """Precondition of the test below: the walk finds modules of every package."""
    assert {name.split(".")[1] for name in MODULES} == {p.split(".")[1] for p in PACKAGES.values()}


@pytest.mark.parametrize("name", MODULES)
def test_the_docstring_examples_hold(name: str):
    module = importlib.import_module(name)
    runner = doctest.DocTestRunner(optionflags=FLAGS)
    with np.printoptions(legacy=False):
        for test in doctest.DocTestFinder().find(module, name):
            runner.run(test)
    result = runner.summarize(verbose=False)
    assert result.attempted > 0, f"{name} has '>>>' lines but no docstring example doctest finds"
    assert result.failed == 0, f"{result.failed} of {result.attempted} examples of {name} failed"
