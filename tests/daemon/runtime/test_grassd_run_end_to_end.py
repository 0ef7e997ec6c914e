"""End to end: `grassd run` as a subprocess against simulated controllers on ptys and a pymodbus
lux sensor that this test owns (so it can unplug them), with a datagram socket standing in for
systemd's $NOTIFY_SOCKET."""

from __future__ import annotations

import base64
import io
import json
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from daemon_harness import CACHE, SITE, truncated_exr
from daemon_harness import wait_for as harness_wait_for

from grassd.daemon.core.config.settings import load_default_config
from grassd.daemon.core.errors import DaemonNotRunning
from grassd.daemon.core.runtime.control import request
from grassd.daemon.core.store.history import History
from grassd.firmware_proto.tables import table_crc
from grassd.rigs.processes import end_process
from grassd.rigs.simulated_site import SimulatedHardware, hardware_toml

GRASSD = str(Path(sys.executable).parent / "grassd")


def config_text(state: Path, cfg, extra: str = "", baud: int = 115200) -> str:
    m = cfg.light.modbus
    return f"""state_dir = "{state}"
cache_dir = "{CACHE}"
[site]
latitude = 35.0
longitude = 139.0
timezone = "Asia/Tokyo"
{hardware_toml(cfg, baud)}[[viewpoints]]
h_cm = 170
d_m = 2
[light]
inbox = "inbox"
lux = "modbus"
settle_s = 0.2
incomplete_timeout_s = 2.0
[light.modbus]
host = "127.0.0.1"
port = {m.port}
words = 2
scale = 0.1
timeout_s = 0.5
retries = 1
[schedule]
interval_s = 0
[simulation]
samples = 64
seed = 2
lengths = 7
[calibration]
check_levels = 5
max_rounds = 1
replicates = 2
max_jump_mm = 20.0
{extra}"""


class Daemon:
    """A `grassd run` subprocess plus the simulated hardware and notify socket it talks to."""

    def __init__(self, root: Path, baud: int | None = None, lux: float = 4000.0,
                 firmware: str = "model") -> None:
        self.root = root
        self.state = root / "state"
        self.hw = SimulatedHardware(load_default_config(), root / "hw", lux=lux, baud=baud,
                                    firmware=firmware)
        self.cfg = self.hw.start()
        self.config = root / "grassd.toml"
        self.config.write_text(config_text(self.state, self.cfg, baud=baud or 115200))
        self.notify_path = str(root / "notify.sock")
        self.notify = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self.notify.bind(self.notify_path)
        self.notify.setblocking(False)
        self.messages: list[str] = []
        self.proc: subprocess.Popen | None = None
        self.log = root / "daemon.log"

    def start(self) -> None:
        self.drain()
        self.messages.clear()
        env = {**os.environ, "NOTIFY_SOCKET": self.notify_path, "WATCHDOG_USEC": "1000000"}
        self.proc = subprocess.Popen([GRASSD, "run", "--config", str(self.config), "--tick",
                                      "0.2"], env=env, stdout=open(self.log, "ab"),
                                     stderr=subprocess.STDOUT)
        wait_for(lambda: "READY=1" in self.drain(), 60, "daemon READY=1", self)

    def drain(self) -> str:
        while True:
            try:
                self.messages.append(self.notify.recv(4096).decode())
            except BlockingIOError:
                return "\n".join(self.messages)

    def ctl(self, cmd: str, **kw) -> dict:
        return request(self.state / "control.sock", {"cmd": cmd, **kw}, timeout_s=120)

    def status(self) -> dict:
        return self.ctl("status")["status"]

    def stop(self, sig=signal.SIGTERM, timeout=30) -> int:
        assert self.proc is not None
        self.proc.send_signal(sig)
        rc = self.proc.wait(timeout)
        self.proc = None
        return rc

    def close(self) -> None:
        if self.proc is not None:  # SIGTERM first: a clean exit also saves Taichi's kernel cache
            end_process(self.proc, 30)
        self.hw.stop()
        self.notify.close()

    def crcs(self) -> list[int | None]:
        return [None if (t := dev.active_table()) is None else table_crc(t)
                for bus in self.hw.buses for dev in bus.controllers]

    def drop(self, name: str, manifest: str, files: dict[str, bytes | Path] | None = None) -> Path:
        """Write a directory bundle atomically (hidden name, then rename)."""
        tmp = self.state / "inbox" / f".{name}"
        tmp.mkdir(parents=True)
        for fname, content in (files if files is not None else {"sky.exr": SITE}).items():
            if isinstance(content, Path):
                shutil.copy(content, tmp / fname)
            else:
                (tmp / fname).write_bytes(content)
        (tmp / "manifest.toml").write_text(manifest)
        os.rename(tmp, self.state / "inbox" / name)
        return self.state / "inbox" / name

    def history(self) -> History:
        return History(self.state / "state.db")


def manifest(i: int, lux: float | None = None, extra: str = "") -> str:
    # light times grow with i: light older than the active table's is superseded, not applied
    text = f'timestamp = 2026-06-21T{8 + i // 60:02d}:{i % 60:02d}:00+09:00\nhdri = "sky.exr"\n'
    if lux is not None:
        text += f"ambient_lux = {lux}\n"
    return text + extra


def wait_for(cond, timeout: float, what: str, daemon: Daemon | None = None):
    """:func:`daemon_harness.wait_for`, draining ``daemon``'s output and failing at once if
    it exits."""
    if daemon is None:
        return harness_wait_for(cond, timeout, what, poll=0.1)

    def drained() -> object:
        daemon.drain()
        return cond()

    def alive() -> None:
        if daemon.proc is not None and daemon.proc.poll() is not None:
            raise AssertionError(f"daemon exited ({daemon.proc.returncode}) while waiting for "
                                 f"{what}:\n{daemon.log.read_text()[-3000:]}")

    return harness_wait_for(drained, timeout, what, poll=0.1, check=alive,
                            context=lambda: daemon.log.read_text()[-3000:])


def runs_ok(d: Daemon) -> int:
    return d.status()["run_counts"]["ok"]


@pytest.fixture(scope="module")
def daemon(tmp_path_factory):
    d = Daemon(tmp_path_factory.mktemp("e2e"))
    d.start()
    yield d
    d.close()


def test_good_bundle_reaches_every_controller(daemon):
    d = daemon
    assert "READY=1" in d.drain() and f"MAINPID={d.proc.pid}" in d.drain()
    d.drop("first", manifest(1, lux=9000.0))
    wait_for(lambda: d.status()["health"] == "ok", 60, "first table on all controllers", d)
    st = d.status()
    table = st["desired_table"]
    assert d.crcs() == [table["table_crc"]] * 2
    with d.history() as h:
        run = h.run(table["run_id"])
        assert run.status == "ok" and run.lux == 9000.0 and run.lux_source == "manifest"
        assert len(run.lengths_um) == 256 and set(run.input_hashes) == {"sky.exr",
                                                                        "manifest.toml"}
        assert [p.ok for p in h.pushes(run.id)] == [True, True]
        assert Path(run.report_path).is_file() and Path(run.plot_path).is_file()
    assert st["inbox"]["archive"] == 1
    # manifest without lux: the Modbus sensor (4000 lx) is read
    d.drop("sensor", manifest(2))
    wait_for(lambda: runs_ok(d) == 2, 60, "second run", d)
    with d.history() as h:
        assert (h.runs(1)[0].lux, h.runs(1)[0].lux_source) == (4000.0, "modbus")
    wait_for(lambda: d.status()["health"] == "ok", 30, "second table everywhere", d)
    assert "WATCHDOG=1" in d.drain() and "STATUS=" in d.drain()


def test_bad_bundles_rejected_daemon_healthy_old_table_kept(daemon):
    d = daemon
    before = d.status()["desired_table"]
    crcs = d.crcs()
    d.drop("corrupt", manifest(3, 1000.0), {"sky.exr": truncated_exr()})
    d.drop("neglux", manifest(4, -5))
    half = d.state / "inbox" / "half"           # manifest written, HDRI never arrives
    half.mkdir()
    (half / "manifest.toml").write_text(manifest(5, 1000.0))
    d.drop("noraw", manifest(6, 1000.0, 'checker_raw = "chart.dng"\n'
                                        'checker_corners = [[0, 0], [9, 0], [9, 9], [0, 9]]\n'))

    def reasons():
        out = {}
        for p in (d.state / "rejected").iterdir():
            out[p.name.split("-", 1)[1]] = (p / "reason.txt").read_text()
        return out if len(out) == 4 else None

    got = wait_for(reasons, 60, "four rejections", d)
    print("\n" + "\n".join(f"  {k}: {v.strip()}" for k, v in sorted(got.items())))
    assert "HDRI" in got["corrupt"] or "EXR" in got["corrupt"]
    assert "ambient_lux: -5 lux is impossible" in got["neglux"]
    assert "missing file(s) sky.exr" in got["half"]
    assert "missing file(s) chart.dng" in got["noraw"]
    assert d.ctl("ping")["pid"] == d.proc.pid
    st = d.status()
    assert st["desired_table"] == before and st["health"] == "ok"
    assert d.crcs() == crcs
    with d.history() as h:
        assert {j.name for j in h.journal("rejected")} == {"corrupt", "neglux", "half", "noraw"}


def test_unplugged_controller_is_reconciled(daemon):
    d = daemon
    old = d.crcs()
    n = runs_ok(d)
    d.hw.buses[1].unplug(down_s=6.0)
    d.drop("unplug", manifest(7, 2500.0))
    wait_for(lambda: runs_ok(d) == n + 1, 60, "run with one controller unplugged", d)
    st = d.status()
    run_id = st["desired_table"]["run_id"]

    def pushes():
        with d.history() as h:
            p = [x for x in h.pushes(run_id) if x.kind == "push"]
        return p if len(p) == 2 else None

    got = wait_for(pushes, 30, "push results", d)
    assert [(p.controller.endswith("#1"), p.ok) for p in got] == [(True, True), (False, False)]
    assert "serial port" in got[1].error
    new = st["desired_table"]["table_crc"]
    assert d.crcs()[0] == new and d.crcs()[1] == old[1]  # old table kept, not a mix
    assert not d.status()["controllers"][1]["in_sync"]
    wait_for(lambda: d.status()["health"] == "ok", 30, "reconcile after replug", d)
    assert d.crcs() == [new, new]
    with d.history() as h:
        assert any(p.kind == "reconcile" and p.ok for p in h.pushes(st["desired_table"]["run_id"]))


def test_sighup_with_broken_config_keeps_old(daemon):
    d = daemon
    good = d.config.read_text()
    d.config.write_text(good.replace("[[viewpoints]]", "[[viewpoints]]\nbogus = 1", 1))
    d.proc.send_signal(signal.SIGHUP)
    st = wait_for(lambda: (s := d.status())["reload_error"] and s, 20, "reload refused", d)
    assert "viewpoints[0].bogus: unknown key" in st["reload_error"]
    assert "RELOADING=1" in d.drain()
    n = runs_ok(d)
    d.drop("after-hup", manifest(8, 3000.0))  # still calibrates with the old config
    wait_for(lambda: runs_ok(d) == n + 1, 60, "run after refused reload", d)
    d.config.write_text(good.replace("samples = 64", "samples = 49"))
    d.proc.send_signal(signal.SIGHUP)
    wait_for(lambda: d.status()["reload_error"] is None, 20, "reload accepted", d)


def test_calibrate_now_over_socket_and_cli(daemon, tmp_path):
    d = daemon
    n = runs_ok(d)
    out = tmp_path / "run.json"
    r = subprocess.run([GRASSD, "calibrate", "--now", "--wait", "--json", str(out), "--config",
                        str(d.config)], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stdout + r.stderr
    res = json.loads(out.read_text())
    assert res["status"] == "ok" and res["run_id"] and "daemon run" in r.stderr + r.stdout
    assert runs_ok(d) == n + 1
    with d.history() as h:
        assert h.run(res["run_id"]).trigger == "request"
    r = subprocess.run([GRASSD, "status", "--config", str(d.config)], capture_output=True,
                       text=True, timeout=120)
    assert r.returncode == 0 and "daemon: running" in r.stdout and "in sync" in r.stdout
    r = subprocess.run([GRASSD, "history", "--config", str(d.config), "-n", "50"],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0 and "request" in r.stdout and "rejected" in r.stdout


def test_memory_flat_over_many_bundles(daemon):
    """Bundles in a row: RSS after the first 5 vs after all; printed for the record."""
    d = daemon
    count = int(os.environ.get("GRASSD_E2E_BUNDLES", "15"))
    n0 = runs_ok(d)
    rss = []
    t0 = time.monotonic()
    for i in range(count):
        d.drop(f"many{i:03d}", manifest(100 + i, 1000.0 + i))
        wait_for(lambda i=i: runs_ok(d) >= n0 + i + 1, 60, f"bundle {i}", d)
        rss.append(d.status()["rss_mb"])
    took = time.monotonic() - t0
    print(f"\n{count} bundles in {took:.1f} s ({took / count:.2f} s each); RSS MiB after "
          f"bundle 1: {rss[0]:.1f}, 5: {rss[4]:.1f}, {count}: {rss[-1]:.1f}")
    assert rss[-1] - rss[4] < 25.0


def test_sigterm_during_push_then_restart_resumes(tmp_path):
    """Slow line (4800 baud, ~1.3 s per table): SIGTERM while pushing exits cleanly; every
    controller holds either the old or the new table; a restart finishes the job, once."""
    d = Daemon(tmp_path, baud=4800)
    try:
        d.start()
        d.drop("base", manifest(20, 5000.0))
        wait_for(lambda: d.status()["health"] == "ok", 90, "first table", d)
        old = d.status()["desired_table"]["table_crc"]
        # a sun from the south, where it stands in Tokyo (the site) then; newer than "base"
        d.drop("next", 'timestamp = 2026-11-10T11:30:00+09:00\nhdri = "sky.exr"\n'
                       "ambient_lux = 800.0\nsun_lux = 30000.0\nsun_azimuth_deg = 180.6\n"
                       "sun_elevation_deg = 37.9\n")
        def pushing_next() -> bool:  # the new table's push, not a late one of the old table
            st = d.status()
            return st["activity"].startswith("pushing") \
                and st["desired_table"]["table_crc"] != old

        wait_for(pushing_next, 60, "push of the new table started", d)
        t0 = time.monotonic()
        assert d.stop() == 0
        print(f"\nexit {time.monotonic() - t0:.1f} s after SIGTERM during a push")
        assert "STOPPING=1" in d.drain()
        with d.history() as h:
            new = h.current_table().table_crc
            assert h.run_count("ok") == 2
        assert new != old
        mid = d.crcs()
        assert all(c in (old, new) for c in mid), mid  # never a half or mixed table
        assert not (d.state / "control.sock").exists()
        d.start()
        wait_for(lambda: d.status()["health"] == "ok", 90, "reconciled after restart", d)
        assert d.crcs() == [new, new]
        st = d.status()
        assert st["run_counts"]["ok"] == 2 and st["inbox"]["archive"] == 2  # nothing re-run
        assert d.stop() == 0
    finally:
        d.close()


def test_one_shot_calibrate_without_daemon(tmp_path):
    hw_cfg = load_default_config()
    hw = SimulatedHardware(hw_cfg, tmp_path / "hw", lux=6000.0)
    cfg = hw.start()
    try:
        conf = tmp_path / "grassd.toml"
        conf.write_text(config_text(tmp_path / "state", cfg))
        with pytest.raises(DaemonNotRunning):
            request(tmp_path / "state" / "control.sock", {"cmd": "ping"})
        r = subprocess.run([GRASSD, "calibrate", "--now", "--json", "-", "--config", str(conf)],
                           capture_output=True, text=True, timeout=180)
        assert r.returncode == 0, r.stderr
        res = json.loads(r.stdout)
        assert res["status"] == "ok" and res["metrics"]["rounds"] == 1
        assert [c["ok"] for c in res["controllers"]] == [True, True]
        assert "one-shot run" in r.stderr
        crcs = {table_crc(dev.active_table()) for b in hw.buses for dev in b.controllers}
        assert crcs == {res["table_crc"]}
        r = subprocess.run([GRASSD, "status", "--config", str(conf)], capture_output=True,
                           text=True, timeout=120)
        assert "daemon: not running" in r.stdout and "health: ok" in r.stdout
    finally:
        hw.stop()


def test_demo_runs_the_whole_daemon(tmp_path, monkeypatch):
    """`make demo`'s daemon part: embedded default config on simulated hardware, the light
    captured by the capture station from a simulated camera (no bundle dropped by hand)."""
    from grassd.daemon.cli.demo_daemon import run_demo

    monkeypatch.setenv("GRASSD_CACHE_DIR", CACHE)
    lines: list[str] = []
    st = run_demo(tmp_path, echo=lines.append, timeout_s=300)
    assert st.health.level == "ok" and st.run_counts.ok == 1
    assert all(c.in_sync for c in st.controllers) and len(st.controllers) == 2
    run = st.runs[0]
    # the capture station read the simulated sensor and wrote its lux into the bundle
    assert run.lux_source == "manifest" and run.lux == pytest.approx(5000.0)
    assert Path(run.report).is_file() and Path(run.plot).is_file()
    assert any(line.startswith("report: ") for line in lines)
    # content: the demo's animation played through the new table
    shown = next(line for line in lines if line.startswith("content: script"))
    assert "(wave.gif)" in shown and "map nearest_de00" in shown, shown
    out = float(shown.split(", ")[1].split()[0])
    assert out >= 0.9 * 30, shown  # frames/s to the controllers at [content] fps
    # the operator's view: where the status page and the metrics are, both written
    page = tmp_path / "state" / "reports" / "index.html"
    prom = tmp_path / "state" / "metrics" / "grassd.prom"  # always here with simulated hardware
    assert f"status page: {page}" in lines and f"metrics:     {prom}" in lines
    assert "<title>grassd: ok</title>" in page.read_text()
    # its picture of the display as the controllers reported it, the wave across it
    assert (f"status page: {page} (with a picture of the display as its controllers "
            "reported it)") in lines
    m = re.search(r'<figure class="shown"><img src="data:image/png;base64,([^"]+)".*?'
                  r"<figcaption>(.*?)</figcaption>", page.read_text(), re.S)
    assert m and "from 2 of 2 controller(s)" in m.group(2)
    from PIL import Image

    picture = np.asarray(Image.open(io.BytesIO(base64.b64decode(m.group(1)))).convert("RGB"))
    assert len(np.unique(picture.reshape(-1, 3), axis=0)) > 2  # not one flat colour
    from prometheus_client.parser import text_string_to_metric_families

    samples = {s.name: s.value for f in text_string_to_metric_families(prom.read_text())
               for s in f.samples}
    assert samples["grassd_health"] == 0 and samples["grassd_table_id"] == run.id
    assert not (tmp_path / "state" / "control.sock").exists()  # daemon stopped cleanly
