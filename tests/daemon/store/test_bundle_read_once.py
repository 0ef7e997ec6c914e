"""A bundle's files in the main flow: each opened and hashed once at ingest, the panorama's header
checked from that same open file, and the panorama decoded once per attempt, counted on a real
in-process daemon (simulated controllers on ptys, a Modbus lux sensor) by an audit hook on
``open`` and by counting the decoder's calls."""

from __future__ import annotations

import collections
import sys
from collections.abc import Callable
from pathlib import Path

import pytest
from daemon_harness import drop, service, write_config

from grassd.sim import hdri

_WATCHED: list[Callable[[str], None]] = []


def _audit(event: str, args: tuple) -> None:
    if event == "open" and _WATCHED and isinstance(args[0], str | bytes | Path):
        for watch in _WATCHED:
            watch(str(args[0]))


sys.addaudithook(_audit)  # a hook stays for the process: it only counts while a test watches


@pytest.fixture
def opened() -> collections.Counter:
    """File names opened while the test runs (by any code in this process), counted."""
    seen: collections.Counter = collections.Counter()

    def watch(path: str) -> None:
        seen[Path(path).name] += 1

    _WATCHED.append(watch)
    yield seen
    _WATCHED.remove(watch)


def _count_calls(monkeypatch, module, name: str) -> collections.Counter:
    """Count the calls of ``module.name`` wherever it was imported by name."""
    original = getattr(module, name)
    calls: collections.Counter = collections.Counter()

    def counted(path, *args, **kwargs):
        calls[Path(path).name] += 1
        return original(path, *args, **kwargs)

    for mod in list(sys.modules.values()):
        if getattr(mod, name, None) is original:
            monkeypatch.setattr(mod, name, counted)
    return calls


@pytest.mark.parametrize("flat", [False, True], ids=["directory", "flat"])
def test_each_file_is_opened_hashed_and_decoded_once(tmp_path, hw, monkeypatch, opened, flat):
    _, cfg = hw
    svc = service(write_config(tmp_path / "g.toml", tmp_path / "state", cfg))
    inbox = svc.cfg.light.inbox
    drop(inbox, "b1", lux=1000.0)
    if flat:  # the same bundle as flat files: b1.exr, then b1.manifest.toml
        d = inbox / "b1"
        (d / "sky.exr").rename(inbox / "b1.exr")
        text = (d / "manifest.toml").read_text().replace('"sky.exr"', '"b1.exr"')
        (d / "manifest.toml").unlink()
        d.rmdir()
        (inbox / ".b1.manifest.toml").write_text(text)
        (inbox / ".b1.manifest.toml").rename(inbox / "b1.manifest.toml")
    sky = "b1.exr" if flat else "sky.exr"
    decoded = _count_calls(monkeypatch, hdri, "load_hdri")
    hashed = collections.Counter()
    from grassd.daemon.core.store import untrusted

    real_hash = untrusted.hash_regular

    def counting_hash(path, *args, **kwargs):
        hashed[Path(path).name] += 1
        return real_hash(path, *args, **kwargs)

    for mod in list(sys.modules.values()):
        if getattr(mod, "hash_regular", None) is real_hash:
            monkeypatch.setattr(mod, "hash_regular", counting_hash)
    opened.clear()
    svc.tick()
    table = svc.history.current_table()
    svc.shutdown()
    assert table is not None and table.light_bundle is not None
    manifest = "b1.manifest.toml" if flat else "manifest.toml"
    assert opened[manifest] == 1, opened  # read once by the scan, hashed from those bytes
    assert hashed[manifest] == 0 and hashed[sky] == 1, hashed
    assert decoded == {sky: 1}, decoded  # the one attempt decodes it once
    # once at ingest (hashed, header checked from that open file), and twice by the one
    # decode (its first bytes, then the EXR library reading the pixels by name)
    assert opened[sky] == 3, opened
