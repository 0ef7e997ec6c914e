"""``grassd fit``: the grass pixel's materials from photos of it."""

from __future__ import annotations

import json
from pathlib import Path

import click

from grassd.daemon.core.store.atomic import atomic_write_text
from grassd.daemon.offline.fit_config import FitSettings


def _holdout(_ctx: click.Context, _param: click.Parameter, values: tuple[str, ...]
             ) -> tuple[tuple[float, float, float], ...]:
    from grassd.sim.errors import SceneError
    from grassd.sim.scene import Viewpoint

    out = []
    for text in values:
        try:
            vp = Viewpoint.parse(text)
        except SceneError as exc:
            raise click.BadParameter(str(exc)) from None
        out.append((vp.h_cm, vp.d_m, vp.theta_deg))
    return tuple(out)


@click.command("fit")
@click.argument("capture", type=click.Path(path_type=Path))
@click.option("--holdout", multiple=True, callback=_holdout, metavar="H,D,THETA",
              help="A viewpoint (cm, m, deg) judged but not fitted (every series taken "
                   "there); repeat for several.")
@click.option("--params", default=None, metavar="NAMES",
              help="Comma list of the fields to fit (default: yellow_srgb, green_srgb, "
                   "base_srgb, specular, smoothness, splay_deg); the rest stay as the "
                   "capture's [pixel] says.")
@click.option("--json", "json_out", type=click.Path(dir_okay=False, path_type=Path),
              required=True, help="Write the JSON report here.")
@click.option("--toml", "toml_out", type=click.Path(dir_okay=False, path_type=Path),
              help="Write a [display.pixel] table for grassd.toml here.")
@click.option("--html", "html_out", type=click.Path(dir_okay=False, path_type=Path),
              help="Write the HTML report (real, starting and fitted characteristics).")
@click.option("--samples", type=click.IntRange(16, 65536), default=FitSettings.samples,
              show_default=True,
              help="Camera paths per length per replicate of each layout.")
@click.option("--layouts", type=click.IntRange(2, 32), default=FitSettings.layouts,
              show_default=True,
              help="Random tuft layouts the simulation is averaged over.")
@click.option("--seed", type=click.IntRange(0, 2**31 - 1), default=FitSettings.seed,
              show_default=True, help="Seed of the simulation's paths.")
@click.option("--arch", type=click.Choice(["cpu", "gpu"]), default="cpu", show_default=True)
@click.option("-q", "--quiet", is_flag=True, help="No progress messages.")
def fit(capture, holdout, params, json_out, toml_out, html_out, samples, layouts, seed, arch,
        quiet):
    """Fit the pixel's materials to the photos in CAPTURE (the capture directory that
    ``grassd validate`` reads): albedos, glossy lobe and splay, with standard errors, judged
    per viewpoint against the starting model."""
    from grassd.daemon.offline.colour_chain import chain_text
    from grassd.daemon.offline.experiment import format_table
    from grassd.daemon.offline.fit import fit_capture, parse_params
    from grassd.daemon.offline.validate import load_manifest

    names = parse_params(params)
    manifest = load_manifest(capture)
    settings = FitSettings(samples=samples, layouts=layouts, seed=seed)
    result = fit_capture(manifest, holdout=holdout, params=names, settings=settings, arch=arch,
                         progress=None if quiet else lambda m: click.echo(m, err=True))
    click.echo(format_table(["field", "start", "fitted", "stderr"], result.rows()))
    rows = [[v.fitted.label
             + (" held out" if v.held_out else ""), f"{v.start.frechet:.2f}",
             f"{v.fitted.frechet:.2f}", f"{v.start.max_error:.2f}", f"{v.fitted.max_error:.2f}"]
            for v in result.viewpoints]
    click.echo(format_table(["viewpoint", "Frechet start", "Frechet fitted", "max err start",
                             "max err fitted"], rows))
    for note in result.notes:
        click.echo(f"note: {note}")
    click.echo(f"chi2 {result.chi2:.1f} on {result.dof} degrees of freedom; "
               f"{result.seconds:.1f} s; simulation read through {chain_text(result.chain)}")
    atomic_write_text(json_out, json.dumps(result.to_json(), indent=1))
    click.echo(f"wrote {json_out}")
    if toml_out:
        atomic_write_text(toml_out, result.to_toml())
        click.echo(f"wrote {toml_out}")
    if html_out:
        from grassd.daemon.offline.report import fit_html

        atomic_write_text(html_out, fit_html(result))
        click.echo(f"wrote {html_out}")
