"""``grassd.sim.backend``: Taichi's parallel loops on the CPU go in small tasks that every thread
takes from, so a launch of a few hundred camera paths uses both cores (Taichi's own scheme gave
each thread one block of at least 512 iterations: such a launch ran on one core)."""

# (no "from __future__ import annotations": Taichi reads kernel annotations as objects)

import os

import numpy as np
import pytest

from grassd.sim import backend


@pytest.mark.skipif((os.cpu_count() or 1) < 2, reason="needs 2 CPU cores")
def test_a_loop_of_256_iterations_is_shared_by_the_cpu_threads(renderer):
    ti = backend.ti
    if ti.lang.impl.current_cfg().arch != ti.cpu:
        pytest.skip("CPU thread scheduling")
    who = ti.field(ti.i32, 256)
    sink = ti.field(ti.f32, 256)

    @ti.kernel
    def work():
        for i in range(256):  # each iteration about a millisecond: tasks long enough that the
            acc = 0.0  # second thread starts while the first works, on a busy machine too
            for k in range(60000):
                acc += ti.sin(acc + k * 1e-3)
            sink[i] = acc
            who[i] = ti.global_thread_idx()

    work()
    threads = np.unique(who.to_numpy())
    assert len(threads) >= 2, f"every iteration ran on thread {threads}"
