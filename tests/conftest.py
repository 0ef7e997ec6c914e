"""Shared pytest fixtures. Taichi is initialised once per test process (as the CLI does)."""

from __future__ import annotations

from pathlib import Path

import pytest

SHARED = Path(__file__).resolve().parents[1].parent / "shared"
HDRI_DIR = SHARED / "hdri"


@pytest.fixture(scope="session")
def renderer():
    """One Renderer per test session (kernels compile once; offline cache across sessions)."""
    from grassd.sim.backend import init
    from grassd.sim.renderer import Renderer

    init("cpu")
    return Renderer.shared()


@pytest.fixture(scope="session")
def shared_hdri():
    """Path of a panorama in ../shared/hdri (skips with a reason when shared/ is absent)."""

    def get(name: str) -> Path:
        path = HDRI_DIR / f"{name}.exr"
        if not path.exists():
            pytest.skip(f"{path} not present (CI provides ../shared beside the clone)")
        return path

    return get
