"""The daemon demo (for ``make demo``): the whole service on simulated hardware, end to end.

:func:`run_demo` starts ``grassd run --simulate-hardware`` with the embedded default
configuration plus a ``[capture]`` section (two simulated controllers on pseudo-terminals, a
Modbus/TCP lux sensor and a simulated OSC camera on 127.0.0.1): the capture station
photographs the bundled CC0 site HDRI, reads the sensor and drops the bundle into the inbox by
itself; the demo waits until the new table is active on every controller, prints the status
(with where the status page and the metrics file are) and where the report and plot are,
plays an animation through the new table (``[content]``, as ``grassd show`` asks the daemon)
and says what the display shows, and stops the daemon with SIGTERM.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import TypeVar

from grassd.daemon.cli.run import print_status
from grassd.daemon.core.config.settings import default_config_text
from grassd.daemon.core.errors import ControlError, DaemonError, DaemonNotRunning
from grassd.daemon.core.monitoring.status_types import Status
from grassd.daemon.core.runtime.control import request
from grassd.rigs import FIRMWARE_BACKENDS

#: The demo's capture station: one capture at start (the next an hour later).
DEMO_CAPTURE = '\n[capture]\ncamera = "http://127.0.0.1:8080"\ninterval_s = 3600.0\n'
#: The demo's content: shown through the tables once they are active (receivers on
#: 127.0.0.1, ports chosen by the kernel would not be known to a sender: live is off here)
DEMO_CONTENT = ('\n[content]\nenabled = true\n[content.sacn]\nenabled = false\n'
                '[content.artnet]\nenabled = false\n')
#: seconds the demo's animation plays (its status is read 1 s before the end: the figures
#: per second look back 2 s)
DEMO_SHOW_S = 8.0
#: the demo wave's ends (sRGB 8-bit): dry straw and grass green, as the demo's display shows
WAVE_STRAW_RGB8 = (130, 112, 40)
WAVE_GREEN_RGB8 = (40, 62, 20)

T = TypeVar("T")


def write_wave(path: Path, rows: int, cols: int, frames: int = 12) -> Path:
    """An animated GIF of a green wave crossing a ``rows`` x ``cols`` display (10 px a
    pixel, 0.1 s a frame): the demo's content. Its colours run from :data:`WAVE_STRAW_RGB8`
    to :data:`WAVE_GREEN_RGB8`, inside the range the simulated display shows, so that the
    colour map gives the wave's pixels different levels (brighter greens than the display
    reaches would all map to its lightest level)."""
    import numpy as np
    from PIL import Image

    x = np.arange(cols * 10) / (cols * 10)
    straw, green = np.asarray(WAVE_STRAW_RGB8, float), np.asarray(WAVE_GREEN_RGB8, float)
    images = []
    for k in range(frames):
        g = (0.5 + 0.5 * np.sin(2 * np.pi * (x - k / frames)))[:, None]
        row = np.rint((1.0 - g) * straw + g * green).astype(np.uint8)
        rgb = np.ascontiguousarray(np.broadcast_to(row, (rows * 10, cols * 10, 3)))
        images.append(Image.fromarray(rgb))
    images[0].save(path, save_all=True, append_images=images[1:], duration=100, loop=0)
    return path


def _grassd() -> list[str]:
    exe = Path(sys.executable).parent / "grassd"
    return [str(exe)] if exe.exists() else [sys.executable, "-m", "grassd.daemon.cli"]


def run_demo(workdir: str | os.PathLike[str] | None = None, *, lux: float = 5000.0,
             timeout_s: float = 600.0, echo: Callable[[str], object] = print,
             firmware: str = FIRMWARE_BACKENDS[0]) -> Status:
    """Run the demo in ``workdir`` (default: a new temporary directory, kept) with the simulated
    controllers running ``firmware`` (model, posix or qemu); returns the daemon's final status.
    Raises :class:`DaemonError` if the daemon fails or times out."""
    work = Path(workdir) if workdir else Path(tempfile.mkdtemp(prefix="grassd-demo-"))
    state = work / "state"
    state.mkdir(parents=True, exist_ok=True)
    log = work / "daemon.log"
    sock = state / "control.sock"
    env = {k: v for k, v in os.environ.items()
           if k not in ("RUNTIME_DIRECTORY", "STATE_DIRECTORY", "NOTIFY_SOCKET")}
    config = work / "grassd.toml"  # the default plus a capture station (camera simulated)
    config.write_text(default_config_text() + DEMO_CAPTURE + DEMO_CONTENT)
    cmd = [*_grassd(), "run", "--simulate-hardware", "--config", str(config), "--state-dir",
           str(state), "--sim-lux", str(lux), "--tick", "0.2", "--sim-firmware", firmware]
    echo(f"starting: {' '.join(cmd)}")
    with open(log, "ab") as out:
        proc = subprocess.Popen(cmd, stdout=out, stderr=subprocess.STDOUT, env=env)
    t0 = time.monotonic()

    def status() -> Status:
        return Status.from_json(request(sock, {"cmd": "status"}, timeout_s=30)["status"])

    def wait(cond: Callable[[], T | None], what: str) -> T:
        while time.monotonic() - t0 < timeout_s:
            if proc.poll() is not None:
                raise DaemonError(f"the daemon exited ({proc.returncode}) while {what}; "
                                  f"see {log}")
            try:
                v = cond()
            except DaemonNotRunning:
                v = None
            if v:
                return v
            time.sleep(0.2)
        raise DaemonError(f"timed out after {timeout_s:g} s while {what}; see {log}")

    try:
        wait(lambda: request(sock, {"cmd": "ping"}, timeout_s=5), "starting")
        echo(f"daemon running (pid {proc.pid}), state in {state}")
        echo("the capture station photographs the site (simulated OSC camera) and drops the "
             "bundle into the inbox")

        def pushed() -> Status | None:
            st = status()
            if st.run_counts.rejected or st.run_counts.failed:
                raise DaemonError(f"the demo run did not succeed: {st.runs[0].error}")
            return st if st.health.level == "ok" else None

        st = wait(pushed, "calibrating and pushing")
        echo(f"table active on all controllers after {time.monotonic() - t0:.1f} s")
        print_status(st, echo)
        run = st.runs[0]
        for line in (f"report: {run.report}", f"plot:   {run.plot}", f"log:    {log}"):
            echo(line)
        _show_content(sock, work, echo, st.daemon.status_page if st.daemon else None)
        return status()
    finally:
        if proc.poll() is None:
            proc.terminate()
            try:
                proc.wait(60)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
        if proc.returncode not in (0, None, -15):
            echo(f"daemon exit status {proc.returncode}")


def _show_content(sock: Path, work: Path, echo: Callable[[str], object],
                  page: str | None = None) -> None:
    """Play the demo's animation through the daemon (as ``grassd show`` does), say what
    the display shows meanwhile and whether the status ``page`` holds its picture."""
    from grassd.daemon.content.status import content_line
    from grassd.daemon.core.config.settings import load_default_config

    d = load_default_config().display
    wave = write_wave(work / "wave.gif", d.rows, d.cols)
    ans = request(sock, {"cmd": "content_show", "path": str(wave), "duration_s": DEMO_SHOW_S})
    echo(f"content: the daemon plays {wave.name} ({ans['frames']} frames) for "
         f"{DEMO_SHOW_S:g} s through the active table")
    time.sleep(DEMO_SHOW_S - 1.0)
    content = request(sock, {"cmd": "content_status"}, timeout_s=30)["content"]
    echo(content_line(content))
    if page:
        try:
            pictured = 'class="shown"' in Path(page).read_text("utf-8")
        except OSError:
            pictured = False
        echo(f"status page: {page} (" + ("with a picture of the display as its controllers "
                                         "reported it)" if pictured else
                                         "no picture of the display yet)"))


def main() -> None:
    """Command-line entry: ``python -m grassd.daemon.cli.demo_daemon [WORKDIR]``."""
    try:
        run_demo(sys.argv[1] if len(sys.argv) > 1 else None)
    except (DaemonError, ControlError) as exc:
        print(f"grassd demo: error: {exc}", file=sys.stderr)
        raise SystemExit(2) from None


if __name__ == "__main__":
    main()
