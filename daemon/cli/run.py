"""``grassd check-config``, ``grassd run``, ``grassd status``, ``grassd history`` and
``grassd calibrate --now``: the daemon's command-line face."""

from __future__ import annotations

import os
from collections.abc import Callable
from typing import TYPE_CHECKING

import click

from grassd.daemon.core.config.settings import (
    CONFIG_OPTION_HELP,
    DEFAULT_CONFIG_PATH,
    not_used_by_the_daemon,
    resolve_config,
)
from grassd.daemon.core.safe_text import one_line
from grassd.rigs import FIRMWARE_BACKENDS

if TYPE_CHECKING:
    from grassd.daemon.core.monitoring.status_types import Status



@click.command("check-config")
@click.option("--config", "config_path", type=click.Path(dir_okay=False),
              help=CONFIG_OPTION_HELP)
def check_config(config_path: str | None) -> None:
    """Validate the configuration file and print a summary (exit 2 naming key and line if bad)."""
    cfg = resolve_config(config_path)
    click.echo(f"{cfg.source}: OK")
    click.echo(f"  display: {cfg.display.rows} x {cfg.display.cols} pixels, "
               f"pitch {cfg.display.pitch_mm} mm")
    for c in cfg.controllers:
        ranges = ",".join(f"{a}-{b}" if a != b else str(a) for a, b in c.pixels)
        click.echo(f"  controller {c.port} addr {c.address} @ {c.baud} baud: pixels {ranges}")
    for v in cfg.viewpoints:
        click.echo(f"  viewpoint h={v.h_cm} cm d={v.d_m} m theta={v.theta_deg} deg "
                   f"weight={v.weight}")
    lux = cfg.light.lux
    if cfg.light.modbus is not None:
        m = cfg.light.modbus
        where = f"{m.host}:{m.port}" if m.mode == "tcp" else m.serial_port
        lux += f" (modbus {m.mode} {where} unit {m.unit} fc {m.function_code} reg {m.register})"
    click.echo(f"  inbox: {cfg.light.inbox}; lux from {lux}")
    if (cap := cfg.capture) is not None:
        centre = f"{cap.shutter_s:g} s" if cap.shutter_s else "a metered shutter"
        click.echo(f"  capture: {cap.camera} every {cap.interval_s:g} s, {cap.shots} "
                   f"{cap.file_format} shots {cap.ev_step:g} EV apart around {centre}, ISO "
                   f"{cap.iso}, {cap.white_balance}"
                   + (f"; shaded sensor unit {cap.shaded_unit}" if cap.shaded_unit else ""))
    if (ms := cfg.measure) is not None:
        when = (f"every {ms.interval_s:g} s between {ms.start_hour}:00 and {ms.end_hour}:00"
                if ms.interval_s > 0 else "on request")
        click.echo(f"  measure: camera {ms.camera} {when}, {ms.patterns} patterns, tolerance "
                   f"{ms.tolerance_de00:g} dE00, watchdog {ms.pattern_timeout_s:g} s")
    if (ct := cfg.content) is not None:
        live = [f"{name} {rc.bind}:{rc.port} from universe {u}" for name, rc, u in (
            ("sACN", ct.sacn, ct.sacn.universe), ("Art-Net", ct.artnet, ct.artnet.port_address))
            if rc.enabled]
        click.echo(f"  content: {'on' if ct.enabled else 'off'}, {ct.fps} fps, hold "
                   f"{ct.hold_s:g} s, map {ct.map}; {'; '.join(live) or 'no live receiver'}; "
                   f"{len(ct.playlist)} playlist entr{'y' if len(ct.playlist) == 1 else 'ies'}"
                   f", idle {ct.idle or 'none'}")
        for pic in [e.file for e in ct.playlist] + ([ct.idle] if ct.idle else []):
            if not pic.is_file():
                click.echo(f"  warning: content picture {pic} does not exist (the daemon "
                           "leaves it out until it does and it is reloaded)")
    click.echo(f"  state: {cfg.state_dir}; cache: {cfg.cache_dir}; socket: {cfg.control_socket}")
    from grassd.daemon.core.monitoring.textfile import textfile_path
    from grassd.daemon.core.store.layout import StateLayout

    click.echo(f"  metrics: {textfile_path(cfg.metrics.textfile, cfg.state_dir)}; status page: "
               f"{StateLayout(cfg.state_dir).status_page}; alerts: {cfg.alerts.command or 'none'}")
    for note in not_used_by_the_daemon(cfg):
        click.echo(f"  warning: {note}")


# --------------------------------------------------------------------------- grassd run


def _setup_logging(level: str) -> None:
    from grassd.daemon.core.monitoring.journal import setup_logging

    setup_logging(level)  # journald priorities and fields under systemd


@click.command("run")
@click.option("--config", "config_path", type=click.Path(dir_okay=False),
              help=CONFIG_OPTION_HELP)
@click.option("--state-dir", type=click.Path(file_okay=False),
              help="override the state directory (inbox, database, reports live inside)")
@click.option("--simulate-hardware", is_flag=True,
              help="run against simulated controllers on ptys and a Modbus lux sensor on "
                   "127.0.0.1 (no hardware needed)")
@click.option("--sim-lux", type=float, default=5000.0, show_default=True,
              help="illuminance (lux) the simulated lux sensor reports")
@click.option("--sim-firmware", type=click.Choice(FIRMWARE_BACKENDS),
              default=FIRMWARE_BACKENDS[0], show_default=True,
              help="with --simulate-hardware: the controllers are the Python model, the C "
                   "firmware as a Linux process (posix), or its Cortex-M7 image under QEMU")
@click.option("--sim-display-variation", "variation_file",
              type=click.Path(dir_okay=False, exists=True),
              help="with --simulate-hardware: a camera photographs the simulated display for "
                   "grassd measure, its pixels varied as this TOML says ([[pixel]] index, "
                   "length_offset_mm, green_gain, yellow_gain)")
@click.option("--tick", "tick_s", type=float, default=1.0, show_default=True,
              help="main-loop period (s)")
@click.option("--log-level", default="info", show_default=True,
              type=click.Choice(["debug", "info", "warning", "error"]))
def run_cmd(config_path: str | None, state_dir: str | None, simulate_hardware: bool,
            sim_lux: float, sim_firmware: str, variation_file: str | None, tick_s: float,
            log_level: str) -> None:
    """Run the daemon: watch the inbox, calibrate, push tables, serve the control socket."""
    from grassd.daemon.cli.features import daemon_features
    from grassd.daemon.core.runtime.service import Service
    from grassd.daemon.core.runtime.state_owner import config_as_state_owner

    _setup_logging(log_level)
    cfg = config_as_state_owner(config_path, state_dir, "run")
    if variation_file and not simulate_hardware:
        raise click.UsageError("--sim-display-variation needs --simulate-hardware")
    hw, transform, camera = None, None, None
    if simulate_hardware:
        from grassd.rigs.simulated_site import start_simulated_site

        hw, cfg, transform = start_simulated_site(cfg, sim_lux, sim_firmware)
        if variation_file or cfg.measure is not None:  # the display's measuring camera
            from grassd.daemon.measure.cli import measuring_site

            cfg, transform, camera = measuring_site(hw, cfg, transform, variation_file,
                                                    sim_lux)
            click.echo(f"simulated measuring camera on {camera.url}", err=True)
        for port, dev in hw.ports.items():
            click.echo(f"simulated controller port {port} -> {dev}", err=True)
        if hw.sensor is not None:
            click.echo(f"simulated lux sensor on 127.0.0.1:{hw.sensor.port}", err=True)
        if cfg.capture is not None:
            click.echo(f"simulated OSC camera on {cfg.capture.camera}", err=True)
    src = config_path or (str(DEFAULT_CONFIG_PATH) if DEFAULT_CONFIG_PATH.exists() else None)
    try:
        svc = Service(cfg, features=daemon_features(), config_path=src, tick_s=tick_s,
                      transform=transform)
        code = svc.run()
    finally:
        if camera is not None:
            camera.stop()
        if hw is not None:
            hw.stop()
    raise SystemExit(code)


# --------------------------------------------------------------------------- status / history


def _fmt_time(t: float | None) -> str:
    import datetime as _dt

    if t is None:
        return "-"
    return _dt.datetime.fromtimestamp(t).strftime("%Y-%m-%d %H:%M:%S")


def print_status(st: Status, echo: Callable[[str], object] = click.echo) -> None:
    """Print a status (:func:`grassd.daemon.core.runtime.status.collect_status`, or the control
    socket's answer read back by :meth:`Status.from_json`) as ``grassd status`` shows it, one
    line at a time through ``echo``."""
    live = st.daemon
    echo(f"daemon: {'running, pid ' + str(live.pid) if live else 'not running'}"
         + (f" ({live.activity})" if live and live.activity else ""))
    echo(one_line(f"health: {st.health.summary()}", None))  # its reasons may quote names
    d = st.desired_table
    echo("current table: " + (f"{d.table_id} (crc {d.table_crc:#010x})" if d else "none")
         + (", one per controller" if d and d.per_controller else ""))
    if live and live.inbox:
        echo("bundles: " + ", ".join(f"{k} {v}" for k, v in live.inbox.items()))
    if live and live.reload_error:
        echo(f"last reload refused: {live.reload_error}")
    # the lines below may quote names an uploader chose: one line each, controls escaped
    if live and live.last_error:
        echo(one_line(f"last error: {live.last_error}", None))
    elif live and (seen := live.last_error_seen) and seen.cleared_at:
        echo(one_line(f"last error (cleared {seen.cleared_at}): {seen.at} {seen.error}", None))
    for w in live.waiting_bundles if live else ():
        echo(one_line(f"bundle {w.bundle} waits (retry in {w.retry_in_s:.0f} s): {w.reason}",
                      None))
    if live and (cw := live.compute_wait):
        echo(one_line(f"{cw.trigger} run waits for compute ({cw.attempts} failed, retry in "
                      f"{cw.retry_in_s:.0f} s): {cw.reason}", None))
    if live and (cap := live.capture):
        due = "-" if cap["next_in_s"] is None else f"{cap['next_in_s']:.0f} s"
        echo(f"capture: {cap['camera']} every {cap['interval_s']:g} s, {cap['captures']} "
             f"bundle(s), next in {due}"
             + (f"; last error: {cap['last_error']}" if cap["last_error"] else ""))
    if live and live.content:
        from grassd.daemon.content.status import content_line

        echo(one_line(content_line(live.content), None))
    for p in live.inbox_problems if live else ():
        echo(one_line(f"inbox: {p}", None))
    for q in st.quarantined:
        echo(one_line(f"quarantined bundle {q.bundle} ({q.attempts} interrupted attempts, "
                      f"since {_fmt_time(q.since)}): `grassd bundles retry {q.bundle}` "
                      "runs it again", None))
    echo("controllers:")
    for c in st.controllers:
        tid = "-" if c.table_id is None else str(c.table_id)
        if d and d.per_controller and c.desired_crc is not None:
            tid += f" (own table crc {c.desired_crc:#010x})"
        err = f"  ({c.error})" if c.error and not c.in_sync else ""
        if b := c.push_retry:
            err += f"; {b.failures} failed push(es), next attempt in {b.retry_in_s:.0f} s"
        echo(f"  {c.name}: table {tid}, {c.state}{err}")
    if live and live.lines:
        from grassd.daemon.core.monitoring.line_report import describe_line

        echo("serial lines:")
        for port, q in live.lines.items():
            echo(f"  {describe_line(port, q)}")
    echo("last runs:")
    for r in st.runs:
        extra = (f"R^2 {r.r2:.4f}, max dev {r.max_dev_de00:.2f} dE00"
                 if r.status == "ok" and r.r2 is not None else (r.error or ""))
        echo(one_line(f"  #{r.id} {_fmt_time(r.started_at)} {r.trigger:8s} "
                      f"{r.status:8s} {extra}", None))
        if r.report and r.status == "ok":
            echo(f"      report {r.report}  plot {r.plot}")
    if live and live.status_page:
        echo(f"status page: {live.status_page}")
        echo(f"metrics:     {live.metrics_textfile}")


@click.command("status")
@click.option("--config", "config_path", type=click.Path(dir_okay=False),
              help=CONFIG_OPTION_HELP)
@click.option("--state-dir", type=click.Path(file_okay=False), help="override the state directory")
@click.option("--json", "as_json", is_flag=True, help="print JSON")
def status_cmd(config_path: str | None, state_dir: str | None, as_json: bool) -> None:
    """Last runs, each controller's active table, and health (asks the daemon if it runs)."""
    import json

    from grassd.daemon.core.errors import DaemonNotRunning, HistoryError
    from grassd.daemon.core.monitoring.status_types import Status
    from grassd.daemon.core.runtime.control import request
    from grassd.daemon.core.runtime.state_owner import config_as_state_owner
    from grassd.daemon.core.runtime.status import collect_status
    from grassd.daemon.core.store.history import History
    from grassd.daemon.core.store.layout import StateLayout

    cfg = config_as_state_owner(config_path, state_dir, "status")
    try:
        st = Status.from_json(request(cfg.control_socket, {"cmd": "status"},
                                      timeout_s=10)["status"])
    except DaemonNotRunning:
        db = StateLayout(cfg.state_dir).db
        if (db.parent.is_dir() and not os.access(db.parent, os.X_OK)) or (
                db.exists() and not os.access(db, os.R_OK)):
            raise HistoryError(
                f"no daemon running, and the state database {db} is readable by the daemon's "
                "user only: ask while the daemon runs (members of group grassd-status may), "
                "or run this as root or as user grassd") from None
        if not db.exists():
            raise HistoryError(f"no daemon running and no state database at {db}") from None
        with History(db) as h:
            st = collect_status(h, cfg)
    if as_json:
        click.echo(json.dumps(st.to_json(), indent=2, default=str))
    else:
        print_status(st)


@click.command("history")
@click.option("--config", "config_path", type=click.Path(dir_okay=False),
              help=CONFIG_OPTION_HELP)
@click.option("--state-dir", type=click.Path(file_okay=False), help="override the state directory")
@click.option("-n", "limit", type=int, default=20, show_default=True, help="runs to show")
@click.option("--json", "as_json", is_flag=True, help="print JSON (with tables and pushes)")
def history_cmd(config_path: str | None, state_dir: str | None, limit: int,
                as_json: bool) -> None:
    """The run history: inputs, lux, metrics, table and per-controller push results."""
    import dataclasses
    import json

    from grassd.daemon.core.errors import HistoryError
    from grassd.daemon.core.runtime.state_owner import config_as_state_owner
    from grassd.daemon.core.store.history import History
    from grassd.daemon.core.store.layout import StateLayout

    cfg = config_as_state_owner(config_path, state_dir, "history")
    db = StateLayout(cfg.state_dir).db
    if not db.exists():
        raise HistoryError(f"no state database at {db}: the daemon has not run yet")
    with History(db) as h:
        runs = h.runs(limit)
        pushes = {r.id: h.pushes(r.id) for r in runs}
    if as_json:
        out = [dict(dataclasses.asdict(r), pushes=[dataclasses.asdict(p) for p in pushes[r.id]])
               for r in runs]
        click.echo(json.dumps(out, indent=2))
        return
    for r in runs:
        m = r.metrics
        lux = "-" if r.lux is None else f"{r.lux:.0f} lx ({r.lux_source})"
        line = f"#{r.id} {_fmt_time(r.started_at)} {r.trigger:8s} {r.status:8s} {lux}"
        if r.status == "ok" and m.get("r2_closed_loop") is not None:
            line += f"  R^2 {m['r2_closed_loop']:.4f} max dev {m['max_dev_de00']:.2f} dE00"
        elif r.error:
            line += f"  {r.error}"
        click.echo(line)
        for p in pushes[r.id]:
            click.echo(f"    {p.kind:9s} {p.controller}: "
                       + ("ok" if p.ok else f"failed ({p.error})"))


# --------------------------------------------------------------------------- calibrate


@click.command("calibrate")
@click.option("--now", is_flag=True, required=True, help="calibrate now (required)")
@click.option("--wait", is_flag=True, help="wait for the daemon's run to finish")
@click.option("--force", is_flag=True, help="accept a table that jumps far from the last one")
@click.option("--json", "json_out", type=click.Path(dir_okay=False, allow_dash=True),
              help="write the run's result as JSON to this file ('-' = stdout)")
@click.option("--config", "config_path", type=click.Path(dir_okay=False),
              help=CONFIG_OPTION_HELP)
@click.option("--state-dir", type=click.Path(file_okay=False), help="override the state directory")
@click.option("--simulate-hardware", is_flag=True,
              help="one-shot only: use simulated controllers and lux sensor")
@click.option("--timeout", "timeout_s", type=float, default=3600.0, show_default=True,
              help="seconds to wait for the daemon's run")
@click.option("--scheduler", metavar="ADDRESS",
              help="one-shot only: simulate on the workers of this dask.distributed "
                   "scheduler, e.g. tls://host:8786 (overrides [compute] scheduler; TLS "
                   "files and allow_insecure as there)")
def calibrate_cmd(now: bool, wait: bool, force: bool, json_out: str | None,
                  config_path: str | None, state_dir: str | None, simulate_hardware: bool,
                  timeout_s: float, scheduler: str | None) -> None:
    """Ask the running daemon for a calibration, or run one here when no daemon runs."""
    import json

    from grassd.daemon.core.errors import CalibrationRejected, DaemonNotRunning
    from grassd.daemon.core.runtime.control import request
    from grassd.daemon.core.runtime.state_owner import config_as_state_owner
    from grassd.daemon.core.store.atomic import atomic_write_json

    cfg = config_as_state_owner(config_path, state_dir, "calibrate")
    if scheduler is not None:
        import dataclasses

        from grassd.daemon.compute.config import scheduler_address_problem, security_problem

        if (problem := scheduler_address_problem(scheduler)) is not None:
            raise click.BadParameter(problem, param_hint="--scheduler")
        cfg = cfg.replace(compute=dataclasses.replace(cfg.compute, scheduler=scheduler))
        if (insecure := security_problem(cfg.compute)) is not None:
            raise click.BadParameter(f"[compute] {insecure[1]}", param_hint="--scheduler")
    try:
        ans = request(cfg.control_socket, {"cmd": "calibrate", "force": force, "wait": wait,
                                           "timeout_s": timeout_s},
                      timeout_s=timeout_s + 10 if wait else 30)
        result = ans.get("run") or {"status": "queued", "queued": ans.get("queued")}
        where = "daemon"
        if scheduler is not None:
            click.echo("grassd: note: the running daemon computes with its own [compute] "
                       "scheduler; --scheduler applies to one-shot runs only", err=True)
    except DaemonNotRunning:
        from grassd.daemon.cli.features import daemon_features
        from grassd.daemon.core.runtime.service import Service

        _setup_logging("warning")
        hw = None
        if simulate_hardware:
            from grassd.rigs.simulated_site import start_simulated_site

            hw, cfg, _ = start_simulated_site(cfg, 5000.0)
        try:
            svc = Service(cfg, features=daemon_features())  # the calibrator: compute's, or here
            try:
                result = svc.one_shot(force=force).to_json()
            finally:
                svc.shutdown()
        finally:
            if hw is not None:
                hw.stop()
        where = "one-shot"
    if json_out == "-":
        click.echo(json.dumps(result, indent=2, default=str))
    elif json_out:
        atomic_write_json(json_out, json.loads(json.dumps(result, default=str)))
    status = result.get("status")
    if status == "queued":
        click.echo(f"calibration queued in the running daemon (position {result['queued']})",
                   err=json_out == "-")
        return
    if status != "ok":
        raise CalibrationRejected(f"{where} run {status}: {result.get('error')}")
    m = result["metrics"]
    ok = sum(c["ok"] for c in result["controllers"])
    if m.get("r2_closed_loop") is not None:
        quality = (f"R^2 {m['r2_closed_loop']:.4f}, max deviation {m['max_dev_de00']:.2f} dE00 "
                   f"after {m['rounds']} round(s)")
    else:
        quality = (f"fitted R^2 {m['r2_after_fit']:.4f}, max deviation "
                   f"{m['max_dev_de00']:.2f} dE00")
    if m.get("granularity"):  # a display run: a table per controller / pixel / region
        quality += (f" (worst pixel group); {m['tables']} {m['granularity']} table(s) from "
                    f"{m['table_source']}")
    msg = (f"{where} run {result['run_id']}: table {result['table_id']} "
           f"(crc {result['table_crc']:#010x}) on {ok}/{len(result['controllers'])} "
           f"controllers; {quality}\n"
           f"report {result['report']}\nplot   {result['plot']}")
    click.echo(msg, err=json_out == "-")
