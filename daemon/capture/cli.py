"""``grassd capture`` (one capture into the inbox) and ``grassd camera sim`` (a simulated OSC
camera): the capture station's command-line face (:mod:`grassd.daemon.capture.station`)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import click

from grassd.daemon.core.config.settings import CONFIG_OPTION_HELP
from grassd.rigs import (
    SIM_CAMERA_CAPTURE_MODES,
    SIM_CAMERA_CURVE,
    SIM_CAMERA_CURVES,
    SIM_CAMERA_SCENE_SCALE,
    SIM_CAMERA_WIDTH,
)


@click.command("capture")
@click.option("--camera", help="OSC camera base URL (default: [capture] camera), e.g. "
                               "http://192.168.1.1")
@click.option("--inbox", type=click.Path(file_okay=False),
              help="inbox directory (default: [light] inbox)")
@click.option("--lux", type=float, help="ambient illuminance (lux) to write into the bundle "
                                        "instead of reading [light.modbus]")
@click.option("--username", help="digest-auth user (THETA in Wi-Fi client mode: its ID, e.g. "
                                 "THETAYN10010104)")
@click.option("--password", help="digest-auth password (THETA: the serial digits)")
@click.option("--retries", type=click.IntRange(0, 20), help="attempts after a failure")
@click.option("--config", "config_path", type=click.Path(dir_okay=False),
              help=CONFIG_OPTION_HELP)
@click.option("--state-dir", type=click.Path(file_okay=False),
              help="override the state directory (the camera response cache lives inside)")
def capture_cmd(camera: str | None, inbox: str | None, lux: float | None,
                username: str | None, password: str | None, retries: int | None,
                config_path: str | None, state_dir: str | None) -> None:
    """Take one bracket with the camera, merge it and drop the bundle into the inbox."""
    import logging

    from grassd.daemon.camera.config import CaptureConfig
    from grassd.daemon.capture.station import Station
    from grassd.daemon.core.errors import ConfigError
    from grassd.daemon.core.runtime.state_owner import config_as_state_owner

    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    cfg = config_as_state_owner(config_path, state_dir, "capture")
    cap = cfg.capture
    if cap is None:
        if camera is None:
            raise ConfigError("no camera: pass --camera URL or add a [capture] section",
                              path=cfg.source)
        cap = CaptureConfig(camera=camera)
    changes = {k: v for k, v in (("camera", camera), ("username", username),
                                 ("password", password), ("retries", retries)) if v is not None}
    cap = dataclasses.replace(cap, **changes)
    target = Path(inbox).absolute() if inbox else cfg.light.inbox
    target.mkdir(parents=True, exist_ok=True)
    station = Station(cap, target, cfg.state_dir, None if lux is not None else cfg.light.modbus,
                      site=(cfg.site.latitude, cfg.site.longitude))
    out = station.capture(lux=lux)
    c = out.manifest["capture"]
    click.echo(f"bundle {out.bundle}: {len(c['exposures_s'])} shots, {c['merge_method']} "
               f"({c['response']}), clipped {100 * c['clipped_fraction']:.2f}%"
               + (", sun clipped" if c["sun_clipped"] else "")
               + f", ambient {out.manifest['ambient_lux']:g} lx")


@click.group("camera")
def camera_group() -> None:
    """Cameras of the capture station."""


@camera_group.command("sim")
@click.option("--hdri", required=True, type=click.Path(exists=True, dir_okay=False),
              help="the panorama the camera photographs (.exr or .hdr)")
@click.option("--port", type=int, default=0, show_default=True, help="TCP port (0 = any free)")
@click.option("--curve", type=click.Choice(SIM_CAMERA_CURVES), default=SIM_CAMERA_CURVE,
              show_default=True, help="the camera's response curve")
@click.option("--width", type=int, default=SIM_CAMERA_WIDTH, show_default=True,
              help="largest panorama width served (downsampled by whole factors)")
@click.option("--scene-scale", type=float, default=SIM_CAMERA_SCENE_SCALE, show_default=True,
              help="radiance (cd/m^2) per HDRI unit: the light level")
@click.option("--username", help="require digest auth with this user (as a THETA in client "
                                 "mode)")
@click.option("--password", default="", help="digest-auth password")
@click.option("--capture-mode", type=click.Choice(SIM_CAMERA_CAPTURE_MODES),
              default=SIM_CAMERA_CAPTURE_MODES[0], show_default=True,
              help="the captureMode it starts in (video: it refuses takePicture until a client "
                   "sets image, as a THETA left in video mode)")
def camera_sim_cmd(hdri: str, port: int, curve: str, width: int, scene_scale: float,
                   username: str | None, password: str, capture_mode: str) -> None:
    """Run a simulated OSC camera on 127.0.0.1 that photographs HDRI; prints its URL."""
    import threading

    from grassd.rigs.simulated_camera import sim_camera_from_file

    cam = sim_camera_from_file(hdri, width=width, curve=curve, scene_scale=scene_scale,
                               port=port, username=username, password=password,
                               capture_mode=capture_mode).start()
    click.echo(cam.url, nl=True)
    try:
        threading.Event().wait()
    except KeyboardInterrupt:
        pass
    finally:
        cam.stop()
