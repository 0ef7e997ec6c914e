"""A capture bundle appears in the inbox only once every file in it has reached the disk:
each file's data is fsynced before the rename that makes the bundle visible, so a power cut
right after the rename cannot leave an empty or truncated sky.exr behind a complete-looking
bundle. The camera is a real HTTP server on 127.0.0.1; os.fsync and os.rename are observed,
not replaced."""

from __future__ import annotations

import os

import numpy as np

from grassd.daemon.camera.config import CaptureConfig
from grassd.daemon.capture.station import Station
from grassd.rigs.simulated_camera import SimCamera


def small_env() -> np.ndarray:
    """A 64 x 32 sky: smooth gradient plus a bright compact sun."""
    h, w = 32, 64
    v = np.linspace(1.0, 0.2, h)[:, None, None] * np.ones((h, w, 3))
    v[5:7, 20:22] = 3000.0
    return v.astype(np.float32)


def test_every_bundle_file_is_fsynced_before_the_bundle_appears(tmp_path, monkeypatch):
    events: list[tuple[str, object]] = []
    real_fsync, real_rename = os.fsync, os.rename

    def fsync(fd: int) -> None:
        st = os.fstat(fd)
        events.append(("fsync", (st.st_dev, st.st_ino)))
        real_fsync(fd)

    def rename(src, dst, *a, **kw) -> None:
        real_rename(src, dst, *a, **kw)
        events.append(("rename", os.fspath(dst)))

    inbox = tmp_path / "inbox"
    inbox.mkdir()
    with SimCamera(small_env(), scene_scale=1000.0, latency_s=0.01) as cam:
        st = Station(CaptureConfig(camera=cam.url, shots=5, retries=0, timeout_s=2.0,
                                   command_timeout_s=2.0), inbox, tmp_path / "state")
        st.client.poll_s = 0.01
        monkeypatch.setattr(os, "fsync", fsync)
        monkeypatch.setattr(os, "rename", rename)
        out = st.capture(lux=8000.0)
        monkeypatch.undo()
    appeared = events.index(("rename", os.fspath(out.bundle)))
    synced = {ino for kind, ino in events[:appeared] if kind == "fsync"}
    files = sorted(p for p in out.bundle.iterdir())
    assert {p.name for p in files} == {"sky.exr", "manifest.toml"}
    for p in files:
        st_ = p.stat()
        assert (st_.st_dev, st_.st_ino) in synced, f"{p.name} was not fsynced before the rename"
    assert (os.stat(out.bundle).st_dev, os.stat(out.bundle).st_ino) in synced  # its entries
