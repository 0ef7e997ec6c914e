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


@pytest.fixture
def hw(tmp_path):
    """Simulated controllers on ptys (the embedded default configuration's two buses) and a
    Modbus lux sensor on 127.0.0.1 reading 2500 lux: yields (SimulatedHardware, the Config
    pointing at them); stopped after the test."""
    from grassd.daemon.core.config.settings import load_default_config
    from grassd.rigs.simulated_site import SimulatedHardware

    sim = SimulatedHardware(load_default_config(), tmp_path / "hw", lux=2500.0)
    cfg = sim.start()
    yield sim, cfg
    sim.stop()
