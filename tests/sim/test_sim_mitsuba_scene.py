"""How the exported scene is handed to Mitsuba (numpy side, no Mitsuba needed): the resampled
environment map and the quad's pixel coverage."""

from __future__ import annotations

import numpy as np

from grassd.rigs.mitsuba_scene import _llvm_major, mitsuba_env, quad_coverage, quad_pixels


def _mitsuba_lookup(fine: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Mitsuba 3's envmap lookup (envmap.cpp eval_spectrum): bilinear, columns at (j + 0.5) / W
    with the first column repeated after the last, rows at i / (H - 1)."""
    h, w = fine.shape[:2]
    padded = np.concatenate([fine, fine[:, :1]], axis=1)
    x = (u - 0.5 / w) % 1.0 * w
    y = v * (h - 1)
    i = np.minimum(y.astype(int), h - 2)
    j = np.minimum(x.astype(int), w - 1)
    fy, fx = (y - i)[:, None], (x - j)[:, None]
    return ((1 - fy) * ((1 - fx) * padded[i, j] + fx * padded[i, j + 1])
            + fy * ((1 - fx) * padded[i + 1, j] + fx * padded[i + 1, j + 1]))


def test_resampled_map_reproduces_ours_away_from_borders_and_keeps_the_integral():
    rng = np.random.default_rng(0)
    env = rng.random((16, 32, 3)).astype(np.float32)
    k = 4
    fine = mitsuba_env(env, k)
    assert fine.shape == (16 * k + 1, 32 * k, 3)
    u, v = rng.random(4000), rng.random(4000)
    fu, fv = u * 32 % 1.0, v * 16 % 1.0
    inner = (fu > 0.5 / k) & (fu < 1 - 0.5 / k) & (fv > 1 / k) & (fv < 1 - 1 / k)
    ours = env[(v * 16).astype(int), (u * 32).astype(int)]
    theirs = _mitsuba_lookup(fine, u, v)
    np.testing.assert_allclose(theirs[inner], ours[inner], rtol=1e-6)
    assert np.abs(theirs[~inner] - ours[~inner]).max() > 0.01  # blended near the borders
    # The integral over the sphere (midpoint rule on a fine grid) stays that of our map.
    gu, gv = np.meshgrid((np.arange(2048) + 0.5) / 2048, (np.arange(1024) + 0.5) / 1024)
    sin_t = np.sin(np.pi * gv.ravel())[:, None]
    ours_int = (env[(gv.ravel() * 16).astype(int), (gu.ravel() * 32).astype(int)] * sin_t).mean(0)
    theirs_int = (_mitsuba_lookup(fine, gu.ravel(), gv.ravel()) * sin_t).mean(0)
    np.testing.assert_allclose(theirs_int, ours_int, rtol=2e-4)
    # As handed over unchanged (rows on the poles), the same map is stretched: 1 % off here.
    stretched = (_mitsuba_lookup(env, gu.ravel(), gv.ravel()) * sin_t).mean(0)
    assert np.abs(stretched / ours_int - 1).max() > 2e-3


def test_quad_coverage_is_the_quad_area_and_sits_on_its_pixels():
    doc = {"camera": {"origin": [0.0, -2.0, 1.7], "target": [0.0, 0.0, 0.0],
                      "up": [0.0, 0.0, 1.0], "fov_x_deg": 1.2},
           "quad": [[-0.01675, -0.01675, 0.0], [0.01675, -0.01675, 0.0],
                    [0.01675, 0.01675, 0.0], [-0.01675, 0.01675, 0.0]]}
    width = 200
    q = quad_pixels(doc, width)
    area = 0.5 * abs(np.dot(q[:, 0], np.roll(q[:, 1], -1)) - np.dot(q[:, 1], np.roll(q[:, 0], -1)))
    (x0, y0), w = quad_coverage(doc, width)
    np.testing.assert_allclose(w.sum(), area, rtol=1e-9)
    assert w.min() >= 0.0 and w.max() <= 1.0 + 1e-12
    assert 0 < np.count_nonzero((w > 0) & (w < 1)) < 4 * (w.shape[0] + w.shape[1])
    # The centre pixel is wholly inside; the crop's corner pixel touches the outline at most.
    cx, cy = q.mean(axis=0)
    assert w[int(cy) - y0, int(cx) - x0] == 1.0
    assert w[0, 0] < 1.0


def test_llvm_versions_are_read_from_debian_and_upstream_names():
    assert _llvm_major("/usr/lib/x86_64-linux-gnu/libLLVM-19.so") == 19
    assert _llvm_major("/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1") == 19
    assert _llvm_major("/usr/lib/x86_64-linux-gnu/libLLVM-15.so.1") == 15
    assert _llvm_major("/usr/lib/libfoo.so") == 0
