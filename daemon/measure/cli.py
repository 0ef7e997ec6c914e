"""``grassd measure``: photograph the display under test patterns and correct each pixel.

``grassd measure --now`` runs one measurement here (:mod:`grassd.daemon.measure`), or asks the
running daemon for one. ``grassd measure setup`` photographs the colour checker lying at the
display once, for the measuring camera's colour chain. With ``--simulate-hardware`` everything
is simulated: controllers, lux sensor, and a camera photographing the simulated display, whose
pixels carry the hidden differences of ``--sim-display-variation FILE``; the set-up is then
made by a simulated operator on the first measurement.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import click

from grassd.daemon.core.config.settings import CONFIG_OPTION_HELP, Config
from grassd.rigs import FIRMWARE_BACKENDS

if TYPE_CHECKING:
    from grassd.daemon.camera.client import OscClient
    from grassd.daemon.measure.report import MeasurementReport
    from grassd.rigs.simulated_camera import SimCamera
    from grassd.rigs.simulated_display import SimulatedDisplay
    from grassd.rigs.simulated_site import SimulatedHardware
    from grassd.rigs.spectral_display import SpectralDisplay
    from grassd.sim.lighting import Lighting


def _measure_config(cfg: Config, camera_url: str | None = None) -> Config:
    """``cfg`` with a ``[measure]`` section (the defaults where it has none), its camera
    replaced by ``camera_url`` when given."""
    from grassd.daemon.measure.config import MeasureConfig

    mc = cfg.measure or MeasureConfig(camera=camera_url or "capture")
    if camera_url is not None:
        mc = dataclasses.replace(mc, camera=camera_url, username="", password="")
    return cfg.replace(measure=mc)


def measuring_site(hw: SimulatedHardware, cfg: Config, transform: Callable[[Config], Config],
                   display: SimulatedDisplay | SpectralDisplay, lux: float
                   ) -> tuple[Config, Callable[[Config], Config], SimCamera]:
    """Add a measuring camera photographing ``display`` to ``hw``'s simulated site: (config
    whose ``[measure] camera`` is it, the config transform that keeps it so on reload, the
    camera). Makes the camera's set-up (the simulated operator's checker shot) when the state
    directory has none."""
    from grassd.daemon.core.store.layout import StateLayout

    camera = camera_photographing(display)
    try:
        cfg = _measure_config(cfg, camera.url)
        if not StateLayout(cfg.state_dir).measure_setup.exists():
            simulated_setup(cfg, display, camera.url, lux)
    except BaseException:
        camera.stop()
        raise

    def keep_camera(c: Config) -> Config:
        return _measure_config(transform(c), camera.url)

    return cfg, keep_camera, camera


class SimulatedSite:
    """Simulated controllers and lux sensor (as ``grassd run --simulate-hardware``) plus the
    simulated display and the camera that photographs it (:func:`measuring_site`)."""

    def __init__(self, cfg: Config, variation_file: str | None, lux: float = 5000.0,
                 firmware: str = FIRMWARE_BACKENDS[0]) -> None:
        from grassd.rigs.simulated_site import start_simulated_site

        self.hw, cfg, transform = start_simulated_site(cfg, lux, firmware)
        try:
            self.cfg, _, self.camera = measuring_site(
                self.hw, cfg, transform, simulated_display(self.hw, cfg, variation_file, lux),
                lux)
        except BaseException:
            self.hw.stop()
            raise

    def stop(self) -> None:
        """Stop the camera and the simulated hardware."""
        self.camera.stop()
        self.hw.stop()


def site_lighting(cfg: Config, lux: float) -> Lighting:
    """The simulated site's light: the embedded default HDRI at ``lux``."""
    from grassd.daemon.core.calibration.calibrate import Calibrator
    from grassd.sim.hdri import default_site_hdri
    from grassd.sim.light_input import LightInput

    return Calibrator(cfg).lighting(LightInput(hdri=default_site_hdri(), ambient_lux=lux))


def simulated_display(hw: SimulatedHardware, cfg: Config, variation_file: str | None,
                      lux: float, samples: int = 1024) -> SimulatedDisplay:
    """The simulated display of ``hw``'s controllers, pixels varied as ``variation_file``
    says (or not at all; ``samples`` per length for its pixels' radiance). Initialises the
    renderer."""
    from grassd.daemon.core.calibration.calibrate import init_backend
    from grassd.daemon.core.calibration.display_model import capacity_for
    from grassd.daemon.core.calibration.variation import DisplayVariation, load_variation
    from grassd.rigs.simulated_display import SimulatedDisplay
    from grassd.sim.renderer import Renderer

    n = cfg.display.rows * cfg.display.cols
    variation = (load_variation(variation_file, n) if variation_file
                 else DisplayVariation.none(n))
    init_backend(cfg)
    return SimulatedDisplay(cfg, site_lighting(cfg, lux), variation, hw.positions_um,
                            Renderer.shared(capacity_for(n)), samples=samples)


def start_measuring_camera(hw: SimulatedHardware, cfg: Config, variation_file: str | None,
                           lux: float, samples: int = 1024
                           ) -> tuple[SimulatedDisplay, SimCamera]:
    """:func:`simulated_display` and a started simulated OSC camera photographing it."""
    display = simulated_display(hw, cfg, variation_file, lux, samples)
    return display, camera_photographing(display)


def camera_photographing(display: SimulatedDisplay | SpectralDisplay) -> SimCamera:
    """A started simulated OSC camera whose every shot is ``display``'s view now."""
    import numpy as np

    from grassd.rigs.simulated_camera import SimCamera

    return SimCamera(np.zeros((display.width // 2, display.width, 3), np.float32),
                     scene_scale=1.0, scene_source=display.scene,
                     model="grassd SimCam measuring", seed=12345).start()


def simulated_setup(cfg: Config, display: SimulatedDisplay | SpectralDisplay, camera_url: str,
                    lux: float) -> Path:
    """The simulated operator's set-up: the checker laid at the display, photographed with the
    measuring camera and turned into ``measure/setup.json`` (as ``grassd measure setup``)."""
    from grassd.daemon.measure.job import measuring_camera

    client, _ = measuring_camera(_measure_config(cfg, camera_url))
    display.checker = True
    try:
        return make_setup(cfg, client, display.checker_corners(), lux, display.chart)
    finally:
        display.checker = False


def make_setup(cfg: Config, client: OscClient, corners: Sequence[Sequence[float]], lux: float,
               chart: str = "spydercheckr-24") -> Path:
    """Photograph the checker with ``client`` and save the measuring camera's set-up."""
    from grassd.calib.errors import CheckerPhotoError
    from grassd.daemon.core.store.atomic import atomic_write_json
    from grassd.daemon.core.store.layout import StateLayout
    from grassd.daemon.measure.camera_chain import MeasuringCamera, setup_from_checker

    layout = StateLayout(cfg.state_dir)
    camera = MeasuringCamera(client, layout.measure, cfg.measure.iso)
    for ev in SETUP_EV:  # a checker on a dark ground: the meter overexposes its patches
        shot = camera.shoot("setup-checker", ev)
        try:
            setup = setup_from_checker(shot.raw_path, corners, chart, shot.exposure, lux)
            break
        except CheckerPhotoError as exc:
            if "clipped" not in str(exc) or ev == SETUP_EV[-1]:
                raise
    return atomic_write_json(layout.measure_setup, setup.to_json())


#: Exposures (stops from the metered one) tried for the set-up shot, until no patch is clipped.
SETUP_EV: tuple[float, ...] = (0.0, -2.0, -4.0, -6.0)


@click.group("measure", invoke_without_command=True)
@click.option("--now", is_flag=True, help="measure the display now")
@click.option("--config", "config_path", type=click.Path(dir_okay=False),
              help=CONFIG_OPTION_HELP)
@click.option("--state-dir", type=click.Path(file_okay=False), help="override the state directory")
@click.option("--simulate-hardware", is_flag=True,
              help="simulated controllers, lux sensor and a camera photographing the "
                   "simulated display")
@click.option("--sim-display-variation", "variation_file",
              type=click.Path(dir_okay=False, exists=True),
              help="with --simulate-hardware: TOML of the pixels' hidden differences "
                   "([[pixel]] index, length_offset_mm, green_gain, yellow_gain)")
@click.option("--sim-lux", type=float, default=5000.0, show_default=True,
              help="illuminance (lux) of the simulated site")
@click.option("--json", "json_out", type=click.Path(dir_okay=False, allow_dash=True),
              help="write the measurement's report as JSON here ('-' = stdout)")
@click.pass_context
def measure(ctx: click.Context, now: bool, config_path: str | None, state_dir: str | None,
            simulate_hardware: bool, variation_file: str | None, sim_lux: float,
            json_out: str | None) -> None:
    """Photograph the display under test patterns and correct each pixel's tables."""
    if ctx.invoked_subcommand is not None:
        return
    if not now:
        raise click.UsageError("give --now to measure now (or a sub-command: setup)")
    if variation_file and not simulate_hardware:
        raise click.UsageError("--sim-display-variation needs --simulate-hardware")
    from grassd.daemon.core.errors import DaemonError
    from grassd.daemon.core.runtime.service import Service
    from grassd.daemon.core.runtime.state_owner import config_as_state_owner
    from grassd.daemon.measure.job import measure_with

    cfg = config_as_state_owner(config_path, state_dir, "measure")
    if not simulate_hardware and (report := _ask_daemon(cfg)) is not None:
        _output(report, json_out)
        return
    site = None
    if simulate_hardware:
        site = SimulatedSite(cfg, variation_file, sim_lux)
        cfg = site.cfg
    elif cfg.measure is None:
        raise DaemonError(f"{cfg.source}: no [measure] section; name the measuring camera "
                          '([measure] camera = "capture" or its http:// URL)')
    try:
        svc = Service(cfg)
        try:
            report = measure_with(svc, "request")
        finally:
            svc.shutdown()
    finally:
        if site is not None:
            site.stop()
    _output(report, json_out)


def _ask_daemon(cfg: Config) -> MeasurementReport | None:
    """The running daemon's measurement (it owns the controllers), or None when none runs."""
    from grassd.daemon.core.errors import DaemonNotRunning
    from grassd.daemon.core.runtime.control import request

    try:
        ans = request(cfg.control_socket, {"cmd": "measure", "timeout_s": MEASURE_WAIT_S},
                      timeout_s=MEASURE_WAIT_S + 10)
    except DaemonNotRunning:
        return None
    if "measurement" not in ans:
        from grassd.daemon.core.errors import DaemonError

        raise DaemonError(f"the running daemon refused the measurement: {ans.get('error')}")
    return ans["measurement"]


#: Seconds ``grassd measure --now`` waits for the running daemon's measurement.
MEASURE_WAIT_S: float = 3600.0


def _output(report: MeasurementReport, json_out: str | None) -> None:
    from grassd.daemon.core.store.atomic import atomic_write_json

    if json_out == "-":
        click.echo(json.dumps(report, indent=2, default=str))
    elif json_out:
        atomic_write_json(json_out, json.loads(json.dumps(report, default=str)))
    err = json_out == "-"
    if report.get("status") != "ok":
        click.echo(f"measurement {report.get('measurement')} {report.get('status')}: "
                   f"{report.get('error')}; the last good tables stay active", err=True)
        raise SystemExit(2)
    u, v = report["uniformity"], report["verdict"]
    click.echo(f"measurement {report['measurement']}: {v['state']}; worst pixel pair "
               f"{u['before']:.2f} -> {u['after']:.2f} dE00 at level {u['level']}; tables "
               f"{report['tables'].get('status')} (run {report['tables'].get('run_id')})\n"
               f"report {report.get('report')}", err=err)


@measure.command("setup")
@click.option("--corners", required=True, metavar="'X,Y X,Y X,Y X,Y'",
              help="the checker's patch-area corners in the full-size photo (TL TR BR BL, "
                   "pixels)")
@click.option("--chart", default="spydercheckr-24", show_default=True, help="the checker")
@click.option("--lux", type=float, help="lux at the display now (default: the sensor's)")
@click.option("--config", "config_path", type=click.Path(dir_okay=False),
              help=CONFIG_OPTION_HELP)
@click.option("--state-dir", type=click.Path(file_okay=False), help="override the state directory")
def setup_cmd(corners: str, chart: str, lux: float | None, config_path: str | None,
              state_dir: str | None) -> None:
    """Photograph the colour checker lying at the display (the camera's colour chain)."""
    from grassd.daemon.core.errors import DaemonError
    from grassd.daemon.core.runtime.state_owner import config_as_state_owner
    from grassd.daemon.measure.camera_chain import load_setup
    from grassd.daemon.measure.job import measuring_camera

    cfg = config_as_state_owner(config_path, state_dir, "measure setup")
    if cfg.measure is None:
        raise DaemonError(f"{cfg.source}: no [measure] section; name the measuring camera")
    try:
        pts = [[float(v) for v in p.split(",")] for p in corners.split()]
    except ValueError:
        pts = []
    if len(pts) != 4 or any(len(p) != 2 for p in pts):
        raise click.BadParameter("four X,Y pairs separated by spaces", param_hint="--corners")
    if lux is None:
        if cfg.light.modbus is None:
            raise click.UsageError("no lux sensor configured: give --lux")
        from grassd.daemon.core.hardware.luxsensor import LuxSensor

        with LuxSensor(cfg.light.modbus) as sensor:
            lux = float(sensor.read_lux())
    client, _ = measuring_camera(cfg)
    path = make_setup(cfg, client, pts, lux, chart)
    click.echo(f"measuring camera set up: {path}")
    setup = load_setup(path)
    if setup.ccm_de00 is not None:
        click.echo(f"checker colour correction: mean {setup.ccm_de00[0]:.2f}, max "
                   f"{setup.ccm_de00[1]:.2f} dE00 on the patches, each left out of the "
                   "fit in turn")
