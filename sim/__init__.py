"""Taichi grass-pixel renderer: scene + light + viewpoint -> linear Rec.709 RGB measurements.

Never imports ``grassd.calib``, ``grassd.firmware_proto`` or ``grassd.daemon``. Importing this
package does not initialise Taichi; call :func:`grassd.sim.backend.init` at the program's entry.
Only :mod:`grassd.sim.backend` imports ``taichi``.

API (units in brackets)
-----------------------
Scene (``scene``, ``geometry``, ``camera``)
    ``PixelSpec`` [mm, blades/mm^2, sRGB albedos], ``DisplaySpec(pixel, rows, cols, pitch_mm)``,
    ``Viewpoint(h_cm, d_m, theta_deg)``, ``RenderSettings(samples, replicates, max_bounces,
    seed, light_samples)``, ``parse_lengths("0:20:1")`` [mm]; ``build_scene`` and
    ``triangle_mesh`` (procedural geometry as arrays / triangles [m]).
Light (``hdri``, ``lighting``, ``sun``, ``env_sampler``)
    ``load_hdri(path)`` -> (H, W, 3) linear Rec.709; ``build_lighting(hdri, ambient_lux,
    sun_lux=, sun_azimuth_deg=, sun_elevation_deg=, sun_from_hdri=, rotation_deg=, flip=)`` ->
    ``Lighting`` (scaled env [nits], sun [lux-like], ``horizontal_irradiance_rgb``);
    ``sun_position(lat, lon, when)``; ``find_sun(env)``; ``env_sampler``: the normal-binned
    importance sampling the renderer uses for next-event estimation.
Rendering (``backend``, ``renderer``)
    ``backend.init("cpu" | "gpu")``; ``Renderer().characteristic(display, lighting, viewpoint,
    lengths_mm, settings, pixel_index=0)`` -> ``Measurement`` (``rgb_linear`` [nits],
    ``rgb_stderr``, ``rgb_replicates``, ``seconds``); ``Renderer().preview(...)`` -> image.
Export (``export``)
    ``export_scene(out_dir, display, lighting, viewpoint, length_mm)``: PLY + env.exr +
    scene.json, so any renderer can render the traced scene.
"""
