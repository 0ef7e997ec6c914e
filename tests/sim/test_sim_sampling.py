"""The renderer's random-number helpers: Owen-scrambled Sobol' pairs, their independence across
replicates and dimension pairs, and a path's own stratified light samples."""

# (no "from __future__ import annotations": Taichi reads kernel annotations as objects)


from types import SimpleNamespace

import numpy as np
import pytest

N_MAX = 4096


@pytest.fixture(scope="module")
def k(renderer):  # the renderer fixture initialises Taichi
    from grassd.sim import tifuncs as tf
    from grassd.sim.backend import ti

    out_i = ti.field(ti.i32, N_MAX)
    out_f = ti.Vector.field(2, ti.f32, N_MAX)
    out_u = ti.Vector.field(2, ti.u32, N_MAX)

    @ti.kernel
    def shuffle_all(n: ti.i32, seed: ti.u32):
        for i in range(n):
            out_i[i] = ti.cast(tf.owen_scramble(ti.u32(i), seed) & ti.u32(n - 1), ti.i32)

    @ti.kernel
    def pairs(n: ti.i32, rep_key: ti.u32, pair: ti.i32, n_sub: ti.i32):
        for i in range(n * n_sub):
            u1, u2 = tf.owen_sobol_pair(i // n_sub, n, rep_key, pair, i % n_sub, n_sub)
            out_f[i] = ti.Vector([u1, u2])

    @ti.kernel
    def one_point(n_keys: ti.i32, index: ti.i32, n: ti.i32):
        for key in range(n_keys):
            u1, u2 = tf.owen_sobol_pair(index, n, tf.replicate_key(7, key), 3, 1, 2)
            out_f[key] = ti.Vector([u1, u2])

    @ti.kernel
    def sobol(index0: ti.i32, n: ti.i32):
        for i in range(n):
            x, y = tf.sobol_2d_reversed(ti.u32(index0 + i))
            out_u[i] = ti.Vector([tf.reverse_bits(x), tf.reverse_bits(y)])

    def sobol_points(index0, n):
        sobol(index0, n)
        return out_u.to_numpy()[:n].astype(np.uint64)

    def shuffled(n, seed):
        shuffle_all(n, seed)
        return out_i.to_numpy()[:n]

    def points(n, rep_key, pair, n_sub=1):
        pairs(n, rep_key, pair, n_sub)
        return out_f.to_numpy()[: n * n_sub].astype(np.float64)

    def over_replicates(n_keys, index, n):
        one_point(n_keys, index, n)
        return out_f.to_numpy()[:n_keys].astype(np.float64)

    return SimpleNamespace(shuffled=shuffled, points=points, over_replicates=over_replicates,
                           sobol_points=sobol_points)


def _one_per_interval(u: np.ndarray, bx: int, by: int) -> bool:
    cells = np.floor(u[:, 0] * bx).astype(int) + bx * np.floor(u[:, 1] * by).astype(int)
    return sorted(cells.tolist()) == list(range(bx * by))


def _sobol_by_direction_numbers(i: int) -> tuple[int, int]:
    """Sobol' dimensions 1 and 2 from their definition: x_b = 2^(31 - b), y_0 = 2^31,
    y_b = y_(b-1) xor (y_(b-1) >> 1), xor-ed over the set bits b of i."""
    x = y = 0
    v = 1 << 31
    for b in range(26):
        if i >> b & 1:
            x ^= 1 << (31 - b)
            y ^= v
        v ^= v >> 1
    return x, y


@pytest.mark.parametrize("index0", [0, (1 << 26) - 2048])
def test_sobol_points_follow_the_direction_numbers(k, index0):
    got = k.sobol_points(index0, 2048)
    rng = np.random.default_rng(index0)
    for i in [*range(64), *rng.integers(0, 2048, 64).tolist(), 2047]:
        assert tuple(got[i].tolist()) == _sobol_by_direction_numbers(index0 + i), i


@pytest.mark.parametrize("n", [1, 64, 1024, 4096])
def test_owen_scrambled_index_is_a_permutation(k, n):
    seen = []
    for seed in (0, 12345, 0xDEADBEEF):
        perm = k.shuffled(n, seed)
        assert sorted(perm.tolist()) == list(range(n))
        seen.append(perm)
    if n >= 64:
        assert not np.array_equal(seen[1], seen[2])  # different seeds, different orders


def test_pairs_are_nets_and_decorrelated(k):
    """1024 = 2^10 paths: one point in every elementary interval (32 x 32 squares, 1024 x 1
    and 1 x 1024 strips, 64 x 16 boxes) of every pair; pairs are not aligned."""
    n = 1024
    got = []
    for pair in (1, 2):
        u = k.points(n, 777, pair)
        assert np.all((u >= 0) & (u < 1))
        for bx, by in ((32, 32), (1024, 1), (1, 1024), (64, 16), (16, 64)):
            assert _one_per_interval(u, bx, by), (bx, by)
        got.append(u)
    # two dimension pairs of the same paths are not aligned (no correlation between them)
    assert abs(np.corrcoef(got[0][:, 0], got[1][:, 0])[0, 1]) < 0.1
    assert abs(np.corrcoef(got[0][:, 1], got[1][:, 1])[0, 1]) < 0.1
    assert not np.allclose(k.points(n, 778, 1), got[0])  # another replicate, another net


def test_a_paths_light_samples_are_stratified_too(k):
    """512 paths x 4 samples: the 2048 samples are a net, and each path's own 4 samples lie in
    the 4 different quadrants of the unit square."""
    n, n_sub = 512, 4
    u = k.points(n, 99, 5, n_sub)
    assert _one_per_interval(u, 64, 32) and _one_per_interval(u, 2048, 1)
    quadrant = (np.floor(u[:, 0] * 2) + 2 * np.floor(u[:, 1] * 2)).reshape(n, n_sub)
    assert all(sorted(q.tolist()) == [0, 1, 2, 3] for q in quadrant)


def test_each_point_is_uniform_over_replicates(k):
    """The estimator is unbiased because every single point is uniform on [0, 1)^2 over the
    random scrambles, also for a count of paths that is not a power of two."""
    for index, n in ((5, 4096), (77, 100)):
        u = k.over_replicates(N_MAX, index, n)
        hist, _, _ = np.histogram2d(u[:, 0], u[:, 1], bins=4, range=((0, 1), (0, 1)))
        expected = N_MAX / 16
        chi2 = float(((hist - expected) ** 2 / expected).sum())
        assert chi2 < 45.0, chi2  # 15 degrees of freedom: p < 1e-4


def test_non_power_of_two_counts_stay_in_range_and_spread(k):
    u = k.points(100, 5, 1)
    assert np.all((u >= 0) & (u < 1))
    assert len(np.unique(np.floor(u[:, 0] * 10))) == 10  # every tenth is visited
