"""The renderer's random-number helpers: permutations, padded stratification, CRN keys."""

# (no "from __future__ import annotations": Taichi reads kernel annotations as objects)


import numpy as np
import pytest


@pytest.fixture(scope="module")
def kernels(renderer):  # the renderer fixture initialises Taichi
    from grassd.sim import tifuncs as tf
    from grassd.sim.backend import ti

    out_i = ti.field(ti.i32, 4096)
    out_f = ti.Vector.field(2, ti.f32, 4096)

    @ti.kernel
    def permute_all(n: ti.i32, p: ti.u32):
        for i in range(n):
            out_i[i] = ti.cast(tf.permute(ti.u32(i), ti.u32(n), p), ti.i32)

    @ti.kernel
    def pairs(strata: ti.i32, rep_key: ti.u32, pair: ti.i32):
        for i in range(strata * strata):
            u1, u2 = tf.padded_pair(i, strata, rep_key, tf.pcg_hash(rep_key + ti.u32(i)), pair)
            out_f[i] = ti.Vector([u1, u2])

    return permute_all, pairs, out_i, out_f


@pytest.mark.parametrize("n", [1, 7, 64, 100, 1000, 4096])
def test_permute_is_a_permutation(kernels, n):
    permute_all, _, out_i, _ = kernels
    seen = []
    for p in (0, 12345, 0xDEADBEEF):
        permute_all(n, p)
        perm = out_i.to_numpy()[:n]
        assert sorted(perm.tolist()) == list(range(n))
        seen.append(perm)
    if n >= 64:
        assert not np.array_equal(seen[1], seen[2])  # different seeds, different orders


def test_padded_pairs_are_stratified_and_decorrelated(kernels):
    _, pairs, _, out_f = kernels
    m = 32
    got = []
    for pair in (1, 2):
        pairs(m, 777, pair)
        u = out_f.to_numpy()[: m * m].astype(np.float64)
        assert np.all((u >= 0) & (u < 1))
        cells = np.floor(u * m).astype(int)
        ids = cells[:, 0] + m * cells[:, 1]
        assert sorted(ids.tolist()) == list(range(m * m))  # one sample per stratum
        got.append(u)
    # two dimension pairs of the same paths are not aligned (no correlation between them)
    assert abs(np.corrcoef(got[0][:, 0], got[1][:, 0])[0, 1]) < 0.1
