"""``grassd.sim.backend``'s kernel cache: a directory per set of compile options, and nothing
left behind from before."""

# (no "from __future__ import annotations": Taichi reads kernel annotations as objects)

import os
import subprocess
import sys

from grassd.sim import backend


def test_kernels_are_cached_apart_from_those_compiled_under_other_options(renderer):
    """Taichi's offline cache key leaves the CPU loop options out: a kernel cached under
    Taichi's own scheme would keep it, so the options name the cache's directory."""
    cfg = backend.ti.lang.impl.current_cfg()
    assert os.path.basename(cfg.offline_cache_file_path).startswith("kernels-")
    assert not cfg.make_cpu_multithreading_loop and not cfg.cpu_block_dim_adaptive


def test_kernels_cached_in_the_directory_itself_are_removed_at_start(tmp_path):
    """Before the per-options directory, kernels went in the cache directory itself, where no
    process reads them now and Taichi's clean-up never looks: they go, other files stay."""
    old = [tmp_path / "T0b1d9b7623755b50e69f0da4f9c46a1c5ba5655a910324442514a271bae8a1d4.tic",
           tmp_path / "ticache.tcb"]
    for p in old:
        p.write_bytes(b"old kernel")
    mine = tmp_path / "notes.txt"
    mine.write_text("not Taichi's")
    code = ("from grassd.sim import backend; import sys; "
            "backend.init('cpu', cache_dir=sys.argv[1])")
    subprocess.run([sys.executable, "-c", code, str(tmp_path)], check=True, timeout=120,
                   capture_output=True)
    assert not any(p.exists() for p in old)
    assert mine.read_text() == "not Taichi's"
