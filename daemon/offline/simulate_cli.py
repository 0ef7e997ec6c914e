"""``grassd simulate``: the grass colour characteristic for given light and viewpoints.

Composes the renderer (``grassd.sim``) with the colour pipeline (``grassd.calib``) through
:mod:`grassd.daemon.core.calibration.simulation`. ``grassd simulate export-scene`` writes the traced
scene for other renderers.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import click
import numpy as np

from grassd.daemon.core.config.settings import TRANSPORTS, SimulationConfig
from grassd.daemon.core.store.atomic import (
    atomic_save_figure,
    atomic_write_bytes,
    atomic_write_text,
)
from grassd.daemon.offline.options import RENDER_DEFAULTS, REPLICATES
from grassd.sim.scene import PixelSpec


def _view(_ctx, _param, values):
    from grassd.sim.scene import Viewpoint

    return [Viewpoint.parse(v) for v in values]


def _light_options(f):
    """Options shared by ``simulate`` and ``simulate export-scene``."""
    opts = [
        click.option("--hdri", type=click.Path(dir_okay=False, path_type=Path),
                     help="Equirectangular panorama (.exr or .hdr), linear Rec.709."),
        click.option("--lux", type=float, help="Ambient illuminance on a horizontal meter "
                     "at the display, sun shaded (lux)."),
        click.option("--sun-lux", type=float, default=None,
                     help="Extra horizontal lux of the direct sun (reading with sun - without)."),
        click.option("--sun-azimuth", type=float, default=None,
                     help="Sun compass azimuth (deg, from north, clockwise)."),
        click.option("--sun-elevation", type=float, default=None, help="Sun elevation (deg)."),
        click.option("--site", default=None, metavar="LAT,LON",
                     help="Site latitude,longitude (deg, east +): with --time, the sun "
                     "direction comes from the NREL SPA (pvlib) instead of --sun-azimuth/"
                     "--sun-elevation."),
        click.option("--time", "when", default=None, metavar="ISO8601",
                     help="Time with its UTC offset, e.g. 2026-06-21T14:30+02:00."),
        click.option("--sun-from-hdri", is_flag=True, help="Find the (clipped) sun in the map "
                     "and restore the missing illuminance there; --lux is then the total."),
        click.option("--rotation", type=float, default=0.0, show_default=True,
                     help="Rotate the panorama about the vertical (deg, counter-clockwise)."),
        click.option("--flip", is_flag=True, help="Mirror the panorama east-west first: most "
                     "cameras write panoramas whose columns run clockwise, the opposite of "
                     "the u = atan2(y, x) convention."),
        click.option("--splay", type=float, default=0.0, show_default=True,
                     help="Outward lean of the green blades at full length (deg)."),
        click.option("--specular", type=float, default=0.0, show_default=True,
                     help="Glossy reflectance added to every surface (0 = diffuse only)."),
        click.option("--smoothness", type=float, default=0.5, show_default=True,
                     help="Sharpness of the glossy lobe (0..0.97, Unity-style)."),
        click.option("--bounces", type=int, default=RENDER_DEFAULTS.max_bounces,
                     show_default=True,
                     help="Most surface interactions per path (the default lets Russian "
                     "roulette alone end a path: unbiased)."),
    ]
    for opt in reversed(opts):
        f = opt(f)
    return f


def _deprecated_seed(_ctx, _param, value: int | None) -> None:
    """Warn that ``export-scene --seed`` does nothing: it seeds the Monte Carlo paths of
    ``grassd simulate``, and an exported scene holds no paths."""
    if value is not None:
        click.echo("warning: export-scene --seed is deprecated and does nothing: it seeds the "
                   "camera paths of grassd simulate, and the exported scene traces none; the "
                   "tufts' layout is --layout-seed", err=True)


def _require(**values) -> None:
    missing = [k for k, v in values.items() if v in (None, [], ())]
    if missing:
        raise click.UsageError("missing option(s): " + ", ".join(
            "--" + k.replace("_", "-") for k in missing))


def _sun_from_site(site: str | None, when: str | None, azimuth, elevation):
    """(azimuth, elevation) from --site/--time when given, else the explicit values."""
    if site is None and when is None:
        return azimuth, elevation
    if site is None or when is None:
        raise click.UsageError("--site and --time go together")
    if azimuth is not None or elevation is not None:
        raise click.UsageError("give either --site/--time or --sun-azimuth/--sun-elevation")
    import datetime as dt

    from grassd.sim.sun import sun_position

    try:
        lat, lon = (float(v) for v in site.split(","))
    except ValueError:
        raise click.BadParameter(f"{site!r} must be LAT,LON in degrees",
                                 param_hint="--site") from None
    try:
        moment = dt.datetime.fromisoformat(when)
    except ValueError:
        raise click.BadParameter(f"{when!r} is not an ISO 8601 time",
                                 param_hint="--time") from None
    return sun_position(lat, lon, moment)


def _lighting(hdri, lux, sun_lux, sun_azimuth, sun_elevation, sun_from_hdri, rotation, flip,
              site=None, when=None):
    from grassd.sim.light_input import LightInput

    sun_azimuth, sun_elevation = _sun_from_site(site, when, sun_azimuth, sun_elevation)
    if site is not None and sun_elevation <= 0:
        raise click.BadParameter(f"the sun is below the horizon at {when} "
                                 f"(elevation {sun_elevation:.1f} deg)", param_hint="--time")
    return LightInput(hdri, lux, sun_lux=sun_lux, sun_azimuth_deg=sun_azimuth,
                      sun_elevation_deg=sun_elevation, sun_from_hdri=sun_from_hdri,
                      rotation_deg=rotation, flip=flip).lighting()


def _plot(path: Path, curves) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 4.4), dpi=120)
    for c in curves:
        ax.errorbar(c.lengths_mm, c.ogcd, yerr=c.ogcd_stderr, marker="o", ms=3, capsize=2,
                    label=f"({c.h_cm:g}, {c.d_m:g}, {c.theta_deg:g})")
    ax.set_xlabel("green grass length [mm]")
    ax.set_ylabel("OGCD [CIEDE2000]")
    ax.set_title("Simulated grass colour characteristic")
    ax.grid(alpha=0.3)
    ax.legend(title="(h cm, d m, theta deg)", fontsize=8)
    fig.tight_layout()
    atomic_save_figure(path, fig)
    plt.close(fig)


@click.group(invoke_without_command=True)
@_light_options
@click.option("--seed", type=int, default=0, show_default=True)
@click.option("--view", "views", multiple=True, callback=_view, metavar="H,D,THETA",
              help="Viewpoint: eye height (cm), distance (m), angle (deg). Repeatable.")
@click.option("--lengths", default="0:20:1", show_default=True,
              help="Green lengths in mm: START:STOP:STEP or a comma list (0,5,12.5).")
@click.option("--samples", type=int, default=RENDER_DEFAULTS.samples, show_default=True,
              help="Camera paths per length per replicate.")
@click.option("--replicates", type=REPLICATES, default=RENDER_DEFAULTS.replicates,
              show_default=True,
              help="Independent replicates (their spread gives the standard error).")
@click.option("--target-stderr", type=float, default=None,
              help="Add replicates until every OGCD standard error is at most this (dE00).")
@click.option("--light-samples", type=int, default=RENDER_DEFAULTS.light_samples,
              show_default=True,
              help="Environment shadow rays at the first surface of a path (one at later ones).")
@click.option("--transport", type=click.Choice(TRANSPORTS), default=SimulationConfig.transport,
              show_default=True,
              help="How light is carried: Rec.709 plus the difference spectra make, or "
                   "Rec.709 alone (as [simulation] transport).")
@click.option("--arch", type=click.Choice(["cpu", "gpu"]), default="cpu", show_default=True)
@click.option("--json", "json_out", type=click.Path(dir_okay=False, path_type=Path))
@click.option("--plot", "plot_out", type=click.Path(dir_okay=False, path_type=Path),
              help="PNG of OGCD vs length per viewpoint.")
@click.option("--preview", "preview_out", type=click.Path(dir_okay=False, path_type=Path),
              help="PNG of the first viewpoint's view at the longest length.")
@click.pass_context
def simulate(ctx, hdri, lux, sun_lux, sun_azimuth, sun_elevation, site, when, sun_from_hdri,
             rotation, flip, splay, specular, smoothness, bounces, seed, views, lengths,
             samples, replicates,
             target_stderr, light_samples, transport, arch, json_out, plot_out, preview_out):
    """Simulate the grass colour characteristic (OGCD vs green length) per viewpoint."""
    if ctx.invoked_subcommand is not None:
        return
    _require(hdri=hdri, lux=lux, view=views)
    t0 = time.perf_counter()
    from grassd.daemon.core.calibration.simulation import simulate_curves, white_radiance
    from grassd.sim import backend
    from grassd.sim.scene import DisplaySpec, RenderSettings, parse_lengths

    length_mm = parse_lengths(lengths)
    settings = RenderSettings(samples=samples, replicates=replicates, max_bounces=bounces,
                              seed=seed, light_samples=light_samples)
    display = DisplaySpec(PixelSpec(splay_deg=splay, specular=specular, smoothness=smoothness))
    lighting = _lighting(hdri, lux, sun_lux, sun_azimuth, sun_elevation, sun_from_hdri,
                         rotation, flip, site, when)
    for note in lighting.notes:
        click.echo(f"note: {note}", err=True)
    backend.init(arch)
    from grassd.sim.renderer import Renderer

    renderer = Renderer.shared()
    spectral = None
    if transport == "spectral":
        from grassd.daemon.core.calibration.transport import SpectralTransport

        spectral = SpectralTransport.of(display, lighting, SimulationConfig.spectral_share)
    total = len(views) * len(length_mm)
    with click.progressbar(length=total, label="tracing", file=sys.stderr) as bar:
        curves, seconds = simulate_curves(renderer, display, lighting, views, length_mm,
                                          settings, target_stderr=target_stderr,
                                          spectral=spectral, progress=bar.update)
    seconds["total"] = time.perf_counter() - t0
    for c in curves:
        click.echo(f"\nviewpoint (h, d, theta) = ({c.h_cm:g} cm, {c.d_m:g} m, "
                   f"{c.theta_deg:g} deg)")
        click.echo(f"{'length mm':>10} {'L*':>7} {'a*':>7} {'b*':>7} {'OGCD':>7} {'+-':>6}")
        for x, lab, o, s in zip(c.lengths_mm, c.lab, c.ogcd, c.ogcd_stderr, strict=True):
            click.echo(f"{x:10.2f} {lab[0]:7.2f} {lab[1]:7.2f} {lab[2]:7.2f} {o:7.2f} {s:6.3f}")
    click.echo(f"\n{total} measurements, {settings.strata ** 2} paths per replicate, "
               f"largest OGCD standard error {max(c.ogcd_stderr.max() for c in curves):.3f}; "
               f"seconds: " + ", ".join(f"{k} {v:.2f}" for k, v in seconds.items()))
    if json_out:
        doc = {"viewpoints": [c.to_json() for c in curves], "seconds": seconds,
               "lighting": {"ambient_lux": lighting.ambient_lux, "sun_lux": lighting.sun_lux,
                            "env_scale": lighting.env_scale, "notes": list(lighting.notes)},
               "settings": {"paths_per_replicate": settings.strata ** 2,
                            "replicates": settings.replicates,
                            "target_stderr": target_stderr,
                            "light_samples": settings.light_samples,
                            "max_bounces": settings.max_bounces, "seed": settings.seed}}
        atomic_write_text(json_out, json.dumps(doc, indent=1))
        click.echo(f"wrote {json_out}")
    if plot_out:
        _plot(plot_out, curves)
        click.echo(f"wrote {plot_out}")
    if preview_out:
        import matplotlib

        matplotlib.use("Agg")
        import io

        import matplotlib.pyplot as plt

        img, _quad = renderer.preview(display, lighting, views[0], float(length_mm[-1]))
        srgb = np.clip(img / white_radiance(lighting), 0, 1) ** (1 / 2.2)
        buf = io.BytesIO()
        plt.imsave(buf, srgb, format="png")
        atomic_write_bytes(preview_out, buf.getvalue())
        click.echo(f"wrote {preview_out}")


@simulate.command("export-scene")
@_light_options
@click.option("--length", "length_mm", type=float, required=True, help="Green length (mm).")
@click.option("--view", "views", multiple=True, callback=_view, metavar="H,D,THETA",
              required=True)
@click.option("--out", "out_dir", type=click.Path(file_okay=False, path_type=Path),
              required=True)
@click.option("--layout-seed", type=click.IntRange(min=0), metavar="N",
              default=PixelSpec.layout_seed, show_default=True,
              help="Seed of the tufts' random blade layout the scene is built with.")
@click.option("--seed", type=int, default=None, hidden=True, expose_value=False,
              callback=_deprecated_seed)
def export_scene_cmd(hdri, lux, sun_lux, sun_azimuth, sun_elevation, site, when, sun_from_hdri,
                     rotation, flip, splay, specular, smoothness, bounces, length_mm,
                     views, out_dir, layout_seed):
    """Write the exact traced scene (PLY meshes, env.exr, scene.json) for other renderers."""
    _require(hdri=hdri, lux=lux)
    from grassd.sim.export import export_scene
    from grassd.sim.scene import DisplaySpec, RenderSettings

    lighting = _lighting(hdri, lux, sun_lux, sun_azimuth, sun_elevation, sun_from_hdri,
                         rotation, flip, site, when)
    display = DisplaySpec(PixelSpec(splay_deg=splay, specular=specular, smoothness=smoothness,
                                    layout_seed=layout_seed))
    doc = export_scene(out_dir, display, lighting, views[0], length_mm,
                       settings=RenderSettings(max_bounces=bounces))
    click.echo(f"wrote {out_dir}/scene.json with {len(doc['meshes'])} meshes and env.exr")
