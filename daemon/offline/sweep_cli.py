"""``grassd sweep``: characteristics over HDRIs x times of day x viewpoints x pixel specs.

Runs :func:`grassd.daemon.offline.sweep.run_sweep` on local worker processes (default) or on a Dask
cluster (``--scheduler tls://HOST:8786``, secured by the ``[compute]`` TLS files of ``--config``,
as the daemon's calibrations are); writes ``OUT/sweep.sqlite`` (tidy table ``results``),
``OUT/summary.json`` and ``OUT/summary.png``. Running the same command again resumes: tasks
already in the database are skipped.
"""

from __future__ import annotations

import re
import sys
from typing import TYPE_CHECKING

import click

from grassd.daemon.core.config.settings import DEFAULT_CONFIG_PATH
from grassd.daemon.offline.options import REPLICATES
from grassd.daemon.offline.sweep_config import (
    DEFAULT_CONTRAST_THRESHOLD,
    SWEEP_RETRIES,
    SWEEP_WORKERS,
    SweepSpec,
    spec_default,
)

if TYPE_CHECKING:
    from grassd.daemon.compute.config import ComputeConfig


def _views(_ctx, _param, values):
    from grassd.sim.scene import Viewpoint

    return [(v.h_cm, v.d_m, v.theta_deg) for v in (Viewpoint.parse(t) for t in values)]


def _display(_ctx, _param, value: str) -> tuple[int, int]:
    m = re.fullmatch(r"\s*(\d+)\s*[xX]\s*(\d+)\s*", value)
    if not m:
        raise click.BadParameter("must be ROWSxCOLS, e.g. 1x1 or 8x8")
    return int(m.group(1)), int(m.group(2))


def _pixels(_ctx, _param, values) -> list[tuple[str, tuple]]:
    """``--pixel`` values parsed (field values typed as PixelSpec's fields); a bad one is a
    click usage error naming the field."""
    from grassd.daemon.offline.sweep import SweepError, parse_pixel_option

    try:
        return [parse_pixel_option(v) for v in values]
    except SweepError as exc:
        raise click.BadParameter(str(exc)) from None


def _compute(scheduler: str | None, config_path: str | None
             ) -> tuple[ComputeConfig | None, str | None]:
    """The ``[compute]`` of ``config_path`` (see ``resolve_config``) with ``scheduler``, and
    the file's name; (None, None) without ``scheduler``. A bad address, or a scheduler not
    secured as ``[compute]`` requires, is a usage error of ``--scheduler`` saying how to fix
    it."""
    if scheduler is None:
        return None, None
    import dataclasses

    from grassd.daemon.compute.config import scheduler_address_problem, security_problem
    from grassd.daemon.core.config.settings import resolve_config

    if (problem := scheduler_address_problem(scheduler)) is not None:
        raise click.BadParameter(problem, param_hint="--scheduler")
    cfg = resolve_config(config_path)
    compute = dataclasses.replace(cfg.compute, scheduler=scheduler)
    if (insecure := security_problem(compute)) is not None:
        raise click.BadParameter(f"[compute] {insecure[1]} (read from {cfg.source}; pass "
                                 "the configuration file that sets them with --config)",
                                 param_hint="--scheduler")
    return compute, cfg.source


@click.command("sweep")
@click.option("--hdri", "hdris", multiple=True, required=True,
              type=click.Path(exists=True, dir_okay=False),
              help="Equirectangular panorama (.exr/.hdr). Repeatable. With --scheduler every "
                   "worker must read it at the same path.")
@click.option("--time", "times", multiple=True, metavar="HH:MM",
              help="Local time of day (clear-sky sun and lux at the site). Repeatable; without "
                   "it the light is the HDRI scaled to --lux.")
@click.option("--date", default=None, metavar="YYYY-MM-DD", help="Day of the times.")
@click.option("--latitude", type=float, default=None, help="Site latitude (deg, north +).")
@click.option("--longitude", type=float, default=None, help="Site longitude (deg, east +).")
@click.option("--timezone", default=spec_default("timezone"), show_default=True,
              help="IANA time zone.")
@click.option("--lux", type=float, default=spec_default("lux"), show_default=True,
              help="Ambient lux when no --time is given.")
@click.option("--night-lux", type=float, default=spec_default("night_lux"), show_default=True,
              help="Sky lux when the sun is below 3 deg.")
@click.option("--view", "views", multiple=True, required=True, callback=_views,
              metavar="H,D,THETA", help="Viewpoint (cm, m, deg). Repeatable.")
@click.option("--pixel", "pixels", multiple=True, callback=_pixels, metavar="NAME[:FIELD=V,...]",
              help="Pixel spec variant, e.g. splay10:splay_deg=10. Repeatable "
                   "(default: the standard pixel).")
@click.option("--display", "display", default="1x1", show_default=True, callback=_display,
              help="ROWSxCOLS of the simulated display (its centre pixel is measured).")
@click.option("--lengths", default="0:20:2", show_default=True,
              help="Green lengths in mm: START:STOP:STEP or a comma list.")
@click.option("--samples", type=int, default=spec_default("samples"), show_default=True)
@click.option("--replicates", type=REPLICATES, default=spec_default("replicates"),
              show_default=True)
@click.option("--target-stderr", type=float, default=None,
              help="Add replicates until every OGCD standard error is at most this (dE00).")
@click.option("--bounces", type=int, default=spec_default("bounces"), show_default=True)
@click.option("--light-samples", type=int, default=spec_default("light_samples"),
              show_default=True)
@click.option("--seed", type=int, default=spec_default("seed"), show_default=True,
              help="Mixed into every task's deterministic seed.")
@click.option("--out", "out_dir", required=True,
              type=click.Path(file_okay=False), help="Output directory.")
@click.option("--workers", type=int, default=SWEEP_WORKERS, show_default=True,
              help="Local worker processes (ignored with --scheduler).")
@click.option("--scheduler", default=None, metavar="ADDRESS",
              help="Run on the workers of this dask.distributed scheduler instead of local "
                   "processes, e.g. tls://host:8786, with the TLS files of --config's "
                   "[compute] (tcp:// only with allow_insecure = true there; see "
                   "docs/operating/compute.md).")
@click.option("--config", "config_path", type=click.Path(dir_okay=False),
              help="Configuration file whose [compute] tls_ca_file, tls_cert, tls_key and "
                   f"allow_insecure secure --scheduler (default {DEFAULT_CONFIG_PATH}; the "
                   "embedded default when that is absent).")
@click.option("--retries", type=int, default=SWEEP_RETRIES, show_default=True,
              help="Extra attempts of a failing task on the cluster.")
@click.option("--restart", is_flag=True, help="Discard OUT/sweep.sqlite instead of resuming.")
@click.option("--contrast-threshold", type=float, default=DEFAULT_CONTRAST_THRESHOLD,
              show_default=True,
              help="OGCD range (dE00) below which a condition counts as losing contrast.")
def sweep(hdris, times, date, latitude, longitude, timezone, lux, night_lux, views, pixels,
          display, lengths, samples, replicates, target_stderr, bounces, light_samples, seed,
          out_dir, workers, scheduler, config_path, retries, restart, contrast_threshold):
    """Run characteristics over many conditions; one tidy SQLite table plus summary plots."""
    from grassd.daemon.offline.sweep import conditions, run_sweep
    from grassd.sim.scene import parse_lengths

    compute, source = _compute(scheduler, config_path)

    spec = SweepSpec(lengths_mm=tuple(float(x) for x in parse_lengths(lengths)),
                     samples=samples, replicates=replicates, bounces=bounces,
                     light_samples=light_samples, target_stderr=target_stderr, seed=seed,
                     lux=lux, night_lux=night_lux, latitude=latitude, longitude=longitude,
                     date=date, timezone=timezone, rows=display[0], cols=display[1])
    pix = pixels or [("default", ())]
    conds = conditions(hdris, times, views, pix)
    bar = click.progressbar(length=len(conds), label="sweep", file=sys.stderr)
    state = {"shown": 0}

    def progress(done: int, _total: int) -> None:
        bar.update(done - state["shown"])
        state["shown"] = done

    with bar:
        summary = run_sweep(spec, conds, out_dir, workers=workers, compute=compute,
                            config_source=source, restart=restart, retries=retries,
                            progress=progress,
                            contrast_threshold=contrast_threshold)
    click.echo(f"{summary.total} tasks: {summary.skipped} already stored, {summary.computed} "
               f"computed in {summary.seconds:.1f} s ({summary.tasks_per_s:.2f} tasks/s) on "
               f"{summary.executor}")
    for name, path in summary.files.items():
        click.echo(f"wrote {path}" if name != "database" else f"results in {path}")
    rep = summary.report
    if rep.get("worst_viewpoints"):
        w = rep["worst_viewpoints"][0]
        click.echo("worst viewpoint ({:g}, {:g}, {:g}): OGCD range down to {:.2f} dE00".format(
            *w["view"], w["min_ogcd_range"]))
        click.echo(f"{len(rep['low_contrast'])} of {rep['conditions']} conditions below "
                   f"{rep['contrast_threshold']:g} dE00 OGCD range")
