"""A kernel cache is loaded as code, so a process loads only its own user's: one that belongs to
another user, or that its group or others may write (it or a directory above it), is ignored
with a warning and a private one is used. Real directories with real owners and modes (uid
65534, nobody), and Taichi initialised in a process of its own as the CLI does."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from grassd.sim.kernel_cache import KERNELS, default_cache_dir
from grassd.sim.path_trust import untrusted_part

pytestmark = pytest.mark.skipif(os.geteuid() != 0, reason="needs root: chowns to another uid")

NOBODY = 65534

#: Taichi initialised as the CLI does; prints where its offline cache went (JSON)
_INIT = ("import json, sys; from grassd.sim import backend; "
         "backend.init('cpu', cache_dir=sys.argv[1] if len(sys.argv) > 1 else None); "
         "print(json.dumps(backend.ti.lang.impl.current_cfg().offline_cache_file_path))")


def _init(tmp_path: Path, *cache: Path, env: dict[str, str] | None = None) -> tuple[Path, str]:
    """Where ``backend.init`` put the kernels of a fresh process, and what it wrote to stderr.
    The user's own cache is ``tmp_path/home-cache`` ($XDG_CACHE_HOME)."""
    full = {k: v for k, v in os.environ.items() if k not in ("GRASSD_CACHE_DIR",
                                                             "CACHE_DIRECTORY")}
    full.update(XDG_CACHE_HOME=str(tmp_path / "home-cache"), **(env or {}))
    out = subprocess.run([sys.executable, "-c", _INIT, *map(str, cache)], env=full,
                         capture_output=True, text=True, timeout=120, check=True)
    return Path(json.loads(out.stdout.strip().splitlines()[-1])), out.stderr


def test_root_ignores_a_cache_of_another_user_with_a_warning(tmp_path):
    """The service user's cache (here: nobody's), named to root's process: not loaded, nothing
    written to it; root's own cache instead."""
    theirs = tmp_path / "service-cache" / KERNELS
    theirs.mkdir(parents=True)
    planted = theirs / "ticache.tcb"
    planted.write_bytes(b"their kernels")
    os.chown(theirs, NOBODY, NOBODY)
    os.chown(planted, NOBODY, NOBODY)
    used, err = _init(tmp_path, theirs)
    assert "kernel cache" in err and "ignored" in err and "uid 65534 (nobody)" in err, err
    assert used.parent == tmp_path / "home-cache" / "grassd" / KERNELS
    assert not used.is_relative_to(theirs)
    assert sorted(p.name for p in theirs.iterdir()) == ["ticache.tcb"]
    assert planted.read_bytes() == b"their kernels"


def test_a_cache_others_may_write_is_ignored_and_a_private_one_used(tmp_path):
    """Root's own directory, but writable by its group: ignored. The user's own cache is the
    same directory here, so the fallback is a private directory, gone once the process ends."""
    cache = tmp_path / "home-cache" / "grassd" / KERNELS
    cache.mkdir(parents=True)
    cache.chmod(0o775)
    used, err = _init(tmp_path)  # the default: $XDG_CACHE_HOME/grassd/taichi
    assert "ignored" in err and "writable by its group (mode 0775)" in err, err
    assert used.parent.name.startswith("grassd-kernels-") and not used.is_relative_to(tmp_path)
    assert not used.parent.exists()  # removed at exit


def test_a_cache_below_a_directory_of_another_user_is_ignored(tmp_path):
    """Root owns the cache, but nobody owns the directory above it and could swap it."""
    parent = tmp_path / "theirs"
    cache = parent / "cache"
    cache.mkdir(parents=True)
    os.chown(parent, NOBODY, NOBODY)
    used, err = _init(tmp_path, cache)
    assert f"{parent} belongs to uid 65534 (nobody), not to uid 0 (root)" in err, err
    assert not used.is_relative_to(cache)


def test_own_cache_is_used_without_a_word(tmp_path):
    """Root's own cache, mode 0755 under /tmp (sticky, so it passes as a parent): used."""
    cache = tmp_path / "mine"
    used, err = _init(tmp_path, cache)
    assert used.parent == cache and "ignored" not in err
    assert untrusted_part(cache) is None and (cache.stat().st_mode & 0o777) == 0o700


def test_grassd_cache_dir_keeps_working(tmp_path):
    """$GRASSD_CACHE_DIR (the Makefile's, the tests') names the cache when it is this user's."""
    used, err = _init(tmp_path, env={"GRASSD_CACHE_DIR": str(tmp_path / "env-cache")})
    assert used.parent == tmp_path / "env-cache" / KERNELS and "ignored" not in err


def test_the_default_is_the_users_own_never_the_state_directorys(tmp_path, monkeypatch):
    """Without cache_dir in the file or the environment, a configuration's cache is this
    user's own ($XDG_CACHE_HOME/grassd), wherever its state directory lies."""
    from grassd.daemon.core.config.settings import default_config_text, parse_config

    for var in ("GRASSD_CACHE_DIR", "CACHE_DIRECTORY"):
        monkeypatch.delenv(var, raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    cfg = parse_config(f'state_dir = "{tmp_path / "state"}"\n' + default_config_text())
    assert cfg.cache_dir == default_cache_dir() == tmp_path / "xdg" / "grassd"
    assert not cfg.cache_dir.is_relative_to(cfg.state_dir)


def test_a_link_to_another_users_cache_is_followed_and_ignored(tmp_path):
    """Root's own symbolic link to the service's (nobody's) cache: the target is checked."""
    theirs = tmp_path / "theirs"
    theirs.mkdir()
    os.chown(theirs, NOBODY, NOBODY)
    link = tmp_path / "link"
    link.symlink_to(theirs)
    used, err = _init(tmp_path, link)
    assert f"{theirs} belongs to uid 65534 (nobody)" in err, err
    assert not used.is_relative_to(theirs) and not used.is_relative_to(link)
    assert list(theirs.iterdir()) == []
