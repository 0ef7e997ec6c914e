"""The growth length of a green blade (``tifuncs.hit_growing_blade``), on which the renderer's
reuse of a path across lengths rests: no length below it may hit, and it is not far below the
first length that does."""

# (no "from __future__ import annotations": Taichi reads kernel annotations as objects)


import numpy as np
import pytest

N_RAYS = 1 << 15
LENGTHS = np.linspace(0.0, 0.02, 201)  # m
N_LEN = len(LENGTHS)


@pytest.fixture(scope="module")
def blade_kernel(renderer):  # the renderer fixture initialises Taichi
    from grassd.sim import tifuncs as tf
    from grassd.sim.backend import ti

    orig = ti.Vector.field(3, ti.f32, N_RAYS)
    dirs = ti.Vector.field(3, ti.f32, N_RAYS)
    lengths = ti.field(ti.f32, N_LEN)
    grow = ti.field(ti.f32, N_RAYS)
    hit_plain = ti.field(ti.i32, (N_RAYS, N_LEN))
    hit_growing = ti.field(ti.i32, (N_RAYS, N_LEN))

    @ti.kernel
    def run(p0: tf.vec3, a: tf.vec3, u: tf.vec3, n: tf.vec3, hw: ti.f32, taper: ti.f32,
            tip: ti.f32):
        for i in range(N_RAYS):
            _, g = tf.hit_growing_blade(orig[i], dirs[i], p0, a, u, n, hw, 0.0, taper, tip,
                                        tf.INF)
            grow[i] = g
            for k in range(N_LEN):
                t1 = tf.hit_blade(orig[i], dirs[i], p0, a, u, n, hw, lengths[k], taper, tip,
                                  tf.INF)
                t2, _ = tf.hit_growing_blade(orig[i], dirs[i], p0, a, u, n, hw, lengths[k],
                                             taper, tip, tf.INF)
                hit_plain[i, k] = 1 if t1 < tf.INF else 0
                hit_growing[i, k] = 1 if t2 < tf.INF else 0

    def call(hw: float, taper: float, tip: float, seed: int):
        rng = np.random.default_rng(seed)
        lean = np.radians(15.0)
        a = np.array([1.0, 0.0, 0.0])
        u = np.array([0.0, np.sin(lean), np.cos(lean)])
        n = np.cross(a, u)
        p0 = np.array([0.01, -0.02, -0.005])
        # aim at points near the outline (|s| up to 1.05 hw) at heights up to 21 mm, from
        # either side of the blade, 1-3 m away (a camera's distance: float32 rounding as there)
        s = rng.uniform(-1.05, 1.05, N_RAYS) * hw
        h = rng.uniform(0.0, 0.021, N_RAYS)
        target = p0 + s[:, None] * a + h[:, None] * u
        d = rng.normal(size=(N_RAYS, 3))
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        d *= np.sign(d @ n)[:, None] * rng.choice([-1.0, 1.0], N_RAYS)[:, None]
        o = target - rng.uniform(1.0, 3.0, N_RAYS)[:, None] * d
        orig.from_numpy(o.astype(np.float32))
        dirs.from_numpy(d.astype(np.float32))
        lengths.from_numpy(LENGTHS.astype(np.float32))
        vec = lambda v: ti.Vector(np.asarray(v, np.float32).tolist())  # noqa: E731
        run(vec(p0), vec(a), vec(u), vec(n), hw, taper, tip)
        return grow.to_numpy(), hit_plain.to_numpy(), hit_growing.to_numpy()

    return call


@pytest.mark.parametrize("taper_mm, tip", [(4.0, 0.3), (20.0, 0.999), (4.0, 1.0), (0.5, 0.0)])
def test_no_length_below_the_growth_length_hits(blade_kernel, taper_mm, tip):
    grow, plain, growing = blade_kernel(0.0005, taper_mm * 1e-3, tip, seed=int(taper_mm * 10))
    np.testing.assert_array_equal(plain, growing)  # the same hit test, bit for bit
    below = LENGTHS[None, :] < grow[:, None]
    assert not np.any(plain[below]), "a length below the growth length hits the blade"
    # ... and it is tight: a hit comes within the safety margin (plus one step of the length
    # grid) past it, and a ray that never hits up to 20 mm has a growth length past 20 mm
    hits = plain.any(axis=1)
    first = np.where(hits, LENGTHS[np.argmax(plain, axis=1)], np.inf)
    step = LENGTHS[1] - LENGTHS[0]
    margin = 1e-6 + 8 * 2.0**-24 * taper_mm * 1e-3 / max(1.0 - tip, 1e-6)
    assert np.all(first[hits] <= grow[hits] + step + margin)
    assert np.all(grow[~hits] > LENGTHS[-1] - 1e-6)
    assert hits.mean() > 0.5  # the rays do probe the outline
