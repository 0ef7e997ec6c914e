"""``grassd validate`` (real captures vs simulation) and ``grassd experiment`` (the paper's
experiments; virtual captures for tests and demos)."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import click

from grassd.daemon.core.store.atomic import atomic_write_text
from grassd.daemon.offline.fit_config import FitSettings
from grassd.daemon.offline.options import REPLICATES


def _progress(msg: str) -> None:
    click.echo(msg, err=True)


@click.command("validate")
@click.argument("capture", type=click.Path(path_type=Path))
@click.option("--samples", type=int, default=4096, show_default=True,
              help="Camera paths per length per replicate of the simulation.")
@click.option("--replicates", type=REPLICATES, default=2, show_default=True,
              help="Independent replicates per layout (their spread gives the standard "
                   "error).")
@click.option("--layouts", type=click.IntRange(1, 32), default=FitSettings.layouts,
              show_default=True,
              help="Random tuft layouts the simulation is averaged over, as grassd fit "
                   "averages them (1: the pixel's layout_seed alone).")
@click.option("--target-stderr", type=float, default=None,
              help="Add replicates until every simulated OGCD standard error is at most this.")
@click.option("--seed", type=int, default=0, show_default=True)
@click.option("--arch", type=click.Choice(["cpu", "gpu"]), default="cpu", show_default=True)
@click.option("--json", "json_out", type=click.Path(dir_okay=False, path_type=Path),
              help="Write the JSON report here.")
@click.option("--html", "html_out", type=click.Path(dir_okay=False, path_type=Path),
              help="Write the self-contained HTML report (PNG plots embedded) here.")
@click.option("--pixel", "pixel_file", type=click.Path(dir_okay=False, path_type=Path),
              help="Simulate this pixel: a grassd fit JSON report, or a TOML file with a "
                   "[display.pixel] table (its fields over the capture's [pixel]).")
@click.option("-q", "--quiet", is_flag=True, help="No progress messages.")
def validate(capture, samples, replicates, layouts, target_stderr, seed, arch, json_out,
             html_out, pixel_file, quiet):
    """Compare real captures (RAW photos + capture.toml in CAPTURE) with the simulation.

    Prints, per viewpoint, the discrete Frechet distance, the maximum OGCD error and where it
    occurs, both OGCD ranges, and the 8-bit calibration R^2 before and after calibrating with
    the real and with the simulated characteristic (paper Figure 11).
    """
    from grassd.daemon.offline.colour_chain import chain_text
    from grassd.daemon.offline.validate import load_manifest, validate_capture
    from grassd.sim.scene import MAX_REPLICATES, RenderSettings

    if replicates * layouts > MAX_REPLICATES:
        raise click.BadParameter(f"{replicates} per layout x {layouts} layouts is more than the "
                                 f"{MAX_REPLICATES} replicates one render traces",
                                 param_hint="--replicates")
    manifest = load_manifest(capture)
    if pixel_file is not None:
        from dataclasses import replace

        from grassd.daemon.offline.fit import load_pixel_fields

        manifest = replace(manifest, pixel={**manifest.pixel, **load_pixel_fields(pixel_file)})
    settings = RenderSettings(samples=samples, replicates=replicates, seed=seed)
    result = validate_capture(manifest, settings=settings, arch=arch, layouts=layouts,
                              target_stderr=target_stderr,
                              progress=None if quiet else _progress)
    from grassd.daemon.offline.experiment import format_table

    rows = []
    for v in result.viewpoints:
        c = v.calibration
        rows.append([v.label + (" ref" if v.reference else ""), f"{v.frechet:.2f}",
                     f"{v.max_error:.2f}", f"{v.max_error_length_mm:.2f}",
                     f"{v.real_range:.2f}", f"{v.sim_range:.2f}",
                     f"{c.r2_before:.3f}" if c else "-", f"{c.r2_after_real:.3f}" if c else "-",
                     f"{c.r2_after_sim:.3f}" if c else "-"])
    click.echo(format_table(["viewpoint", "Frechet", "max err", "at mm", "range real",
                             "range sim", "R2 before", "R2 real", "R2 sim"], rows))
    for label, rep in result.repeatability.items():
        click.echo(f"repeatability at {label}: mean std of OGCD {rep['mean_std_ogcd']:.3f} over "
                   f"{rep['trials']} trials (paper's real pixel: 0.42)")
    loo_mean, loo_max = result.ccm.reported_de00
    click.echo(f"checker colour correction ({result.ccm.form}, each patch left out): mean "
               f"{loo_mean:.2f}, max {loo_max:.2f} dE00; seconds: "
               + ", ".join(f"{k} {v:.1f}" for k, v in result.seconds.items()))
    click.echo(f"simulation read through {chain_text(result.chain)}")
    if json_out:
        atomic_write_text(json_out, json.dumps(result.to_json(), indent=1))
        click.echo(f"wrote {json_out}")
    if html_out:
        from grassd.daemon.offline.report import validation_html

        atomic_write_text(html_out, validation_html(result))
        click.echo(f"wrote {html_out}")


@click.group("experiment")
def experiment() -> None:
    """The paper's experiments and virtual captures."""


@experiment.command("paper")
@click.option("--out", "out_dir", type=click.Path(file_okay=False, path_type=Path),
              default=Path("grassd-experiment"), show_default=True,
              help="Directory for the stand-in captures, report.html and report.json.")
@click.option("--hdri-dir", type=click.Path(file_okay=False, path_type=Path), required=True,
              help="Folder with studio/interior/forest/courtyard/city.exr (none ship with "
                   "grassd; the project keeps CC0 ones in shared/hdri beside its sources).")
@click.option("--quick", is_flag=True, help="Few lengths and samples: a smoke run in seconds.")
@click.option("--env", "envs", multiple=True,
              help="Run only these environments ('Env 1' .. 'Env 5'); repeatable.")
@click.option("--samples", type=int, default=None, help="Paths per length per replicate.")
@click.option("--replicates", type=REPLICATES, default=None,
              help="Independent replicates per length (their spread gives the standard error).")
@click.option("--trials", type=click.IntRange(1, 20), default=None,
              help="Repeatability trials at the reference viewpoint (default 3; quick 2).")
@click.option("--arch", type=click.Choice(["cpu", "gpu"]), default="cpu", show_default=True)
@click.option("-q", "--quiet", is_flag=True, help="No progress messages.")
def paper_cmd(out_dir, hdri_dir, quick, envs, samples, replicates, trials, arch, quiet):
    """16 viewpoints x 5 environments as in the paper; prints its tables with timings."""
    from dataclasses import replace

    from grassd.daemon.offline.experiment import (
        ExperimentSettings,
        experiment_html,
        run_paper,
        text_report,
    )
    from grassd.daemon.offline.validate import default_renderer

    st = ExperimentSettings.quick() if quick else ExperimentSettings()
    if envs:
        st = replace(st, environments=tuple(" ".join(e.replace("env", "Env ").split())
                                            if e.lower().startswith("env") else e
                                            for e in envs))
    if samples:
        st = replace(st, samples=samples)
    if replicates:
        st = replace(st, replicates=replicates)
    if trials:
        st = replace(st, trials=trials)
    result = run_paper(out_dir, settings=st, hdri_dir=hdri_dir, renderer=default_renderer(arch),
                       progress=None if quiet else _progress)
    click.echo(text_report(result))
    atomic_write_text(out_dir / "report.json", json.dumps(result.to_json(), indent=1))
    atomic_write_text(out_dir / "report.html", experiment_html(result))
    click.echo(f"wrote {out_dir / 'report.html'} and {out_dir / 'report.json'}")


@experiment.command("virtual-capture")
@click.argument("out_dir", type=click.Path(file_okay=False, path_type=Path))
@click.option("--hdri", type=click.Path(dir_okay=False, path_type=Path), required=True)
@click.option("--lux", type=float, required=True, help="Horizontal illuminance (lux).")
@click.option("--view", "views", multiple=True, default=("170,2,0",), show_default=True,
              metavar="H,D,THETA", help="Viewpoint (cm, m, deg); repeatable; first = reference.")
@click.option("--lengths", default="0:20:2", show_default=True, help="Green lengths in mm.")
@click.option("--splay", type=float, default=0.0, show_default=True,
              help="Blade splay of the photographed pixel (the model keeps 0).")
@click.option("--width", type=int, default=160, show_default=True, help="Photo size (pixels).")
@click.option("--spp", type=int, default=32, show_default=True, help="Samples per pixel.")
@click.option("--read-noise", type=float, default=3.0, show_default=True, help="Electrons.")
@click.option("--bits", type=int, default=14, show_default=True)
@click.option("--seed", type=int, default=0, show_default=True)
@click.option("--arch", type=click.Choice(["cpu", "gpu"]), default="cpu", show_default=True)
def virtual_capture_cmd(out_dir, hdri, lux, views, lengths, splay, width, spp, read_noise, bits,
                        seed, arch):
    """Photograph a simulated pixel with the virtual camera into OUT_DIR (DNGs + capture.toml)
    for ``grassd validate``."""
    from grassd.calib.virtual_camera import VirtualCamera
    from grassd.daemon.offline.validate import default_renderer
    from grassd.daemon.offline.virtual_capture import capture_world
    from grassd.sim.light_input import LightInput
    from grassd.sim.scene import PixelSpec, Viewpoint, parse_lengths

    vps = [Viewpoint.parse(v) for v in views]
    light = LightInput(hdri=hdri.resolve(), ambient_lux=lux)
    renderer = default_renderer(arch)
    with click.progressbar(length=len(vps) * len(parse_lengths(lengths)), label="photographing",
                           file=sys.stderr) as bar:
        m = capture_world(out_dir, light, [(v.h_cm, v.d_m, v.theta_deg) for v in vps],
                          parse_lengths(lengths), real_pixel=PixelSpec(splay_deg=splay),
                          camera=VirtualCamera(read_noise_e=read_noise, bits=bits),
                          renderer=renderer, width=width, spp=spp, seed=seed,
                          progress=lambda _m: bar.update(1))
    click.echo(f"wrote {len(m.photos())} DNGs and {out_dir / 'capture.toml'}")
