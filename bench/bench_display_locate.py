"""Display-in-photo benchmark: render a 4 x 8 display into a 4096 x 2048 equirect
photo pair (sim.display_photo), then locate it and solve the camera pose
(calib.display_in_photo). Prints times and pose errors per camera pose; asserts nothing.

Run: ``.venv/bin/python -m bench.bench_display_locate``. Light: ``../shared/hdri/courtyard.exr``
(every second texel) when present, else a synthetic sky. Photo noise 1 % (Gaussian, relative).
"""

from __future__ import annotations

import time

import numpy as np

from bench import COURTYARD
from grassd.calib.display_in_photo import locate_display, pixel_means
from grassd.sim.display_photo import camera_rotation, display_photo
from grassd.sim.scene import DisplaySpec

POSES = [((0.15, -0.9, 0.7), 30.0), ((0.55, -0.75, 0.65), -20.0), ((-0.1, -1.2, 0.56), 180.0),
         ((0.15, -0.9, 0.7), 99.46), ((0.0, -2.0, 1.5), 90.0)]


def main() -> None:
    if COURTYARD.exists():
        from grassd.sim.hdri import load_hdri

        env = load_hdri(COURTYARD)[::2, ::2]
    else:
        env = np.ones((256, 512, 3), np.float32)
        env[:128] *= 3.0
    display = DisplaySpec(rows=4, cols=8, pitch_mm=33.5)
    rng = np.random.default_rng(0)
    short = np.array([0.21, 0.27, 0.09]) * rng.uniform(0.9, 1.1, (32, 1))
    long = np.array([0.07, 0.18, 0.05]) * rng.uniform(0.9, 1.1, (32, 1))
    locate_display(*(display_photo(env, POSES[0][0], POSES[0][1], display, r, width=2048,
                                   height=1024) for r in (short, long)), 4, 8, 33.5, 33.5)  # warm
    print("camera (m)              yaw    render  locate  pos err  rot err  rms     "
          "mean err  texels/pixel")
    for camera, yaw in POSES:
        t0 = time.perf_counter()
        s_img = display_photo(env, camera, yaw, display, short, frame_radiance=(0.03,) * 3)
        t1 = time.perf_counter()
        l_img = display_photo(env, camera, yaw, display, long, frame_radiance=(0.03,) * 3)
        for img in (s_img, l_img):
            img *= 1.0 + 0.01 * rng.standard_normal(img.shape, dtype=np.float32)
        t2 = time.perf_counter()
        loc = locate_display(s_img, l_img, 4, 8, 33.5, 33.5)
        t3 = time.perf_counter()
        pos = 1000 * np.linalg.norm(loc.pose.position_m - np.array(camera))
        r = loc.pose.rotation @ camera_rotation(yaw).T
        rot = np.degrees(np.arccos(np.clip((np.trace(r) - 1) / 2, -1, 1)))
        mean_err = max(np.abs(pixel_means(s_img, loc) / short - 1).max(),
                       np.abs(pixel_means(l_img, loc) / long - 1).max())
        sizes = loc.region_sizes()
        print(f"{str(camera):22s} {yaw:6.1f}  {t1 - t0:5.2f} s  {t3 - t2:5.2f} s  "
              f"{pos:5.2f} mm  {rot:5.3f}°  {loc.pose.rms_deg:.4f}°  {100 * mean_err:5.2f} %  "
              f"{sizes.min()}-{sizes.max()}")


if __name__ == "__main__":
    main()
