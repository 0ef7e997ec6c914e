"""Hostile input: what each attack costs a running daemon, and a longer fuzz.

1. A `grassd run` subprocess on simulated hardware takes every attack of
   :data:`grassd.rigs.inbox_fuzz.ATTACKS`, one at a time. Before each, the daemon's peak resident
   memory is reset (``5`` written to ``/proc/PID/clear_refs``); the line printed for it holds
   the seconds until the bundle was in rejected/ and the peak RSS (``VmHWM``) meanwhile, beside
   the daemon's RSS when idle. Before the fix, ``dev-zero-manifest`` grew about 350 MB/s until
   MemoryError, and ``fifo-manifest`` never returned.
2. The same daemon's control socket while 16 clients trickle a byte now and then: the latency
   of ``status`` (before the fix every slot was held and ``status`` answered busy), the answer
   to 16 kB of nested JSON (it killed the handler thread) and the daemon's peak RSS.
3. The camera client against a hostile camera on 127.0.0.1 (:mod:`grassd.rigs.hostile_camera`): a
   300 MiB JSON answer, a 300 MiB download, a download trickled one byte a second: seconds
   until the typed error and this process's peak RSS growth.
4. The fuzz of ``tests/daemon/store/test_inbox_fuzz.py``, longer (``--bundles``, default 1000)
   and on another seed: bundles per second and the outcome counts.
5. Each decoder against a file small on disk and huge decoded
   (:mod:`grassd.rigs.hostile_decodes`), in a fresh process: what it did and its peak RSS
   (docs/operating/security.md has the figures).
6. A running ``grassd studio`` under each attack of :mod:`grassd.rigs.hostile_studio`
   (unfinished headers, header floods, a page that never reads, uploads and pictures sent
   four at a time, costly inputs from two pages): what it answered, the seconds a page's
   characteristic then took, and the peak RSS of its server and simulator processes during
   the attack (``VmHWM`` after ``clear_refs``).
7. The compute offload's attacks (:mod:`grassd.rigs.dask_cluster`, a TLS cluster with a site
   CA of its own): a worker of another CA, a worker with a certificate whose answer is a
   pickle that runs a command, and an honest worker, each met by the daemon's Dask client
   (:class:`~grassd.daemon.compute.remote.RemoteCalibrator`, in this process, as
   ``grassd run`` holds it); then the same hostile worker on plain tcp:// read by a client
   with Dask's defaults (the attack is real). What each run did, its seconds, this process's
   peak RSS growth and whether the command ran.

Run: ``python -m bench hostile`` or ``python -m bench.bench_hostile [--bundles N] [--seed S]
[--only PART ...]``.
"""

from __future__ import annotations

import argparse
import logging
import socket
import statistics
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

from bench.daemon_process import BenchDaemon, daemon_config
from grassd.daemon.camera.client import OscClient
from grassd.daemon.core.runtime.control import request
from grassd.rigs.hostile_camera import HostileServer
from grassd.rigs.hostile_decodes import dng_declaring, flat_png, run_child, small_dng
from grassd.rigs.inbox_fuzz import ATTACKS, drop_attack, fuzz_inbox, write_flat_exr
from grassd.rigs.peak_memory import peak_rss_growth, proc_mib

#: The runs of this benchmark: few samples and lengths, one round (seconds a run)
SMALL_RUN = """[simulation]
samples = 64
lengths = 5
[calibration]
check_levels = 5
max_rounds = 1
replicates = 2
"""


def _config(state: Path, cfg) -> str:
    return daemon_config(state, cfg, light="""lux = "manifest"
settle_s = 0.2
incomplete_timeout_s = 2.0
""", tail=SMALL_RUN)


def attacks(limit_s: float = 120.0) -> None:
    """Parts 1 and 2: each attack against one daemon; seconds to rejection and peak RSS
    (MiB); then its control socket under slow and nested clients."""
    d = BenchDaemon("grassd-bench-hostile-", _config, tick_s=0.2)
    try:
        d.wait_ready(120)
        pid = d.proc.pid
        idle = proc_mib(pid)
        print(f"daemon idle: RSS {idle:.0f} MiB")
        print(f"{'attack':28s} {'rejected after':>15s} {'peak RSS':>10s}")
        inbox = d.state / "inbox"
        for name, (build, _) in ATTACKS.items():
            Path(f"/proc/{pid}/clear_refs").write_text("5")
            t0 = time.monotonic()
            drop_attack(inbox, name, build)
            while not any(p.name.endswith(f"-{name}") for p in (d.state / "rejected").iterdir()):
                if time.monotonic() - t0 > limit_s or d.proc.poll() is not None:
                    print(f"{name:28s} {'NOT REJECTED':>15s} (daemon "
                          f"{'exited' if d.proc.poll() is not None else 'still running'})")
                    break
                time.sleep(0.05)
            else:
                peak = proc_mib(pid, "VmHWM")
                print(f"{name:28s} {time.monotonic() - t0:13.2f} s {peak:7.0f} MiB", flush=True)
        control(d)
    finally:
        d.stop()


def control(d: BenchDaemon, slow_clients: int = 16, asks: int = 20) -> None:
    """Part 2: ``status`` while ``slow_clients`` trickle bytes and one sends nested JSON."""
    pid = d.proc.pid
    Path(f"/proc/{pid}/clear_refs").write_text("5")
    slow = []
    for _ in range(slow_clients):
        s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        s.connect(str(d.sock))
        s.send(b"{")
        slow.append(s)
    try:
        times = []
        for _ in range(asks):
            for s in slow:  # a byte now and then, as the attack does
                try:
                    s.send(b" ")
                except OSError:
                    pass  # cut at the deadline: what should happen
            t0 = time.perf_counter()
            request(d.sock, {"cmd": "status"}, timeout_s=10)
            times.append((time.perf_counter() - t0) * 1000)
        raw = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        raw.connect(str(d.sock))
        raw.sendall(b"[" * 8000 + b"]" * 8000 + b"\n")  # under the request cap, over the
        # parser's recursion limit
        raw.settimeout(10)
        answer = raw.recv(200).decode(errors="replace").strip()
        raw.close()
    finally:
        for s in slow:
            s.close()
    peak = proc_mib(pid, "VmHWM")
    print(f"control socket, {slow_clients} slow clients: status {asks}/{asks} answered, median "
          f"{statistics.median(times):.1f} ms, max {max(times):.1f} ms; 16 kB of nested JSON "
          f"answered {answer[:80]}; peak RSS {peak:.0f} MiB")


def camera() -> None:
    """Part 3: the camera client against a hostile camera."""
    with HostileServer() as srv, tempfile.TemporaryDirectory() as tmp:
        srv.trickle_s = 1.0
        cases = [
            ("300 MiB JSON answer", lambda: OscClient(f"{srv.url}/huge", poll_s=0.01).state()),
            ("300 MiB download", lambda: OscClient(srv.url, poll_s=0.01).download(
                f"{srv.url}/huge/x.jpg", Path(tmp) / "a.jpg")),
            ("1 B/s download, 3 s deadline", lambda: OscClient(
                srv.url, poll_s=0.01, download_deadline_s=3.0).download(
                f"{srv.url}/trickle-body/x.jpg", Path(tmp) / "b.jpg")),
        ]
        for what, fn in cases:
            exc, seconds, growth = peak_rss_growth(fn, every_s=0.005)
            print(f"camera: {what:30s} {type(exc).__name__} after {seconds:.2f} s, peak RSS "
                  f"+{growth / (1 << 20):.1f} MiB")


def fuzz(bundles: int, seed: int) -> None:
    """Part 2: ``bundles`` random bundles through an inbox (seed ``seed``)."""
    logging.disable(logging.ERROR)  # one warning per rejected bundle otherwise
    try:
        with tempfile.TemporaryDirectory(prefix="grassd-bench-fuzz-") as tmp:
            t0 = time.perf_counter()
            counts = fuzz_inbox(Path(tmp), seed, bundles)
            dt = time.perf_counter() - t0
    finally:
        logging.disable(logging.NOTSET)
    print(f"fuzz: {bundles} random bundles (seed {seed}) in {dt:.1f} s "
          f"({bundles / dt:.1f} per s): {counts}; no poll blocked or raised")


def decoders() -> None:
    """Part 5: each hostile file through the decoder that meets it, in a fresh process."""
    import json

    from PIL import Image

    from grassd.daemon.measure.camera_chain import Exposure, MeasureSetup

    with tempfile.TemporaryDirectory(prefix="grassd-bench-decodes-") as tmp:
        d = Path(tmp)
        write_flat_exr(d / "sky.exr", [("sky", 8192, 4096, ["B", "G", "R"])], 1.0)
        photo = small_dng(d / "setup.dng")
        dng_declaring(photo, d / "huge.dng", 16384, 8192)
        setup = MeasureSetup((1.0, 1.0, 1.0, 1.0), 1.0, Exposure(0.01, 100, 5.6), 2500.0,
                             ((1.0, 0, 0), (0, 1.0, 0), (0, 0, 1.0)), "spydercheckr-24",
                             str(photo), "2026-11-27T00:00:00+00:00", sensor=(128, 64))
        (d / "setup.json").write_text(json.dumps(setup.to_json()))
        (d / "huge.png").write_bytes(flat_png(8192, 8192))
        Image.new("L", (8192, 8192), 140).save(d / "huge.jpg", "JPEG", quality=50,
                                               progressive=True)
        (d / "capture.toml").write_text("x = " + "[" * 5000 + "]" * 5000 + "\n")
        cases = [
            ("EXR 8192 x 4096, the daemon's calibration", "sky.exr", """
                from grassd.daemon.core.calibration.calibrate import Calibrator
                from grassd.daemon.core.config.settings import resolve_config
                from grassd.sim.light_input import LightInput
                Calibrator(resolve_config(None, None)).lighting(
                    LightInput(hdri=sys.argv[1], ambient_lux=5000.0))"""),
            ("EXR 8192 x 4096, read to the studio's 2048", "sky.exr", """
                from grassd.sim.hdri import load_hdri
                out["shape"] = list(load_hdri(sys.argv[1], max_width=2048).shape)"""),
            ("DNG declaring 16384 x 8192, a measurement shot", "huge.dng", """
                from pathlib import Path
                from grassd.daemon.measure.camera_chain import (Exposure, MeasureSetup, Shot,
                                                                develop_shot)
                setup = MeasureSetup.from_json(json.loads(
                    (Path(sys.argv[1]).parent / "setup.json").read_text()))
                develop_shot(Shot(Path(sys.argv[1]), Exposure(0.01, 100, 5.6)), setup, 2500.0)"""),
            ("PNG 8192 x 8192, the studio's picture", "huge.png", """
                from pathlib import Path
                from grassd.daemon.studio.views import picture_levels
                picture_levels(Path(sys.argv[1]).read_bytes(), 8, 8)"""),
            ("progressive JPEG 8192 x 8192, the studio's picture", "huge.jpg", """
                from pathlib import Path
                from grassd.daemon.studio.views import picture_levels
                picture_levels(Path(sys.argv[1]).read_bytes(), 8, 8)"""),
            ("capture.toml nested 5000 deep, validate", "capture.toml", """
                from grassd.daemon.offline.validate import load_manifest
                load_manifest(sys.argv[1])"""),
        ]
        for what, name, body in cases:
            t0 = time.perf_counter()
            out = run_child(body, str(d / name))
            seconds = time.perf_counter() - t0
            did = out.get("error", "taken") + (f" {out['shape']}" if "shape" in out else "")
            print(f"decode: {what:52s} {did} in {seconds:.1f} s (process), peak RSS "
                  f"{out['peak_mib']:.0f} MiB")


def _studio_condition(**extra: object) -> dict:
    return {"ambient_lux": 5000.0, "viewpoint": [170, 2, 0],
            "lengths_mm": [0, 5, 10, 15, 20], **extra}


def studio() -> None:
    """Part 6: each studio attack against one ``grassd studio``; the peak RSS of its two
    processes during it and how long a page's characteristic then takes."""
    import numpy as np
    from PIL import Image

    from bench import COURTYARD
    from grassd.daemon.studio.limits import DEFAULT_LIMITS
    from grassd.rigs.hostile_studio import (
        answers,
        at_once,
        close_of,
        header_flood,
        never_reading_page,
        unfinished_headers,
    )
    from grassd.rigs.studio_process import start_studio, stop_studio
    from grassd.sim.hdri import write_exr, write_hdr

    costly = _studio_condition(
        lengths_mm=[round(20 * i / 63, 3) for i in range(64)], target_stderr=0.02,
        splay_deg=45, sun_lux=30000, sun_azimuth_deg=180, sun_elevation_deg=15)
    with tempfile.TemporaryDirectory(prefix="grassd-bench-studio-") as tmp:
        d = Path(tmp)
        write_exr(d / "huge.exr", np.full((4096, 8192, 3), 0.5, np.float32), half=True)
        exr = (d / "huge.exr").read_bytes()
        buf = d / "huge.png"
        Image.new("L", (8192, 8192), 140).save(buf, "PNG")
        png = buf.read_bytes()
        skies = []
        for i in range(20):
            write_hdr(d / f"sky{i}.hdr", np.full((1024, 2048, 3), 0.5 + i / 20, np.float32))
            skies.append((d / f"sky{i}.hdr").read_bytes())
        st = start_studio(d, "--hdri", str(COURTYARD))
        try:
            pids = {"server": st.proc.pid, "simulator": st.simulator_pid()}

            def statuses(replies: list[tuple[int, dict]]) -> str:
                return " ".join(str(code) for code, _ in sorted(replies, key=lambda r: r[0]))

            def unfinished() -> str:
                conns = unfinished_headers(st.url, 1050)
                got = answers(conns, time.monotonic() + DEFAULT_LIMITS.header_s + 10)
                codes = statistics.multimode([a[9:12].decode() or "none" for a in got])
                return f"1050 answered, mostly {'/'.join(codes)}"

            def flood() -> str:
                got = answers(header_flood(st.url, 300), time.monotonic() + 10)
                return f"{sum(a.startswith(b'HTTP/1.0 400') for a in got)} of 300 answered 400"

            def never_reads() -> str:
                frames = never_reading_page(
                    st.url, lambda: b"a page's socket was closed" in st.log.read_bytes())
                close = close_of(frames)
                return f"closed {close[0]}" if close else "not closed"

            def uploads() -> str:
                codes = []
                for i, body in enumerate(skies):
                    code, reply = st.request(f"api/hdri?name=sky{i}.hdr", body)
                    if code == 200:
                        code = st.request("api/characteristic", _studio_condition(
                            light=reply["light"]["name"]))[0]
                    codes.append(code)
                return f"20 lit a characteristic each: {codes.count(200)} answered 200"

            def four(path: str, body: bytes, headers: dict | None = None) -> Callable[[], str]:
                return lambda: "4 at once: " + statuses(at_once(
                    lambda: st.request(path, body, headers=headers), 4))

            def two_costly_pages() -> str:
                replies = at_once(lambda: st.request("api/characteristic", costly), 2)
                return "2 costly inputs: " + statuses(replies)

            cases = [
                ("1050 unfinished headers (row 10)", unfinished),
                ("300 requests of 120 x 8000-byte headers", flood),
                ("a page that never reads (row 7)", never_reads),
                ("20 uploaded skies, each used (row 8)", uploads),
                ("8192 x 4096 EXR upload (row 9)", four("api/hdri?name=huge.exr", exr)),
                ("8192 x 8192 PNG picture (row 9)",
                 four("api/picture", png, {"Content-Type": "image/png"})),
                ("64 splayed lengths to 0.02 dE00 (row 11)", two_costly_pages),
            ]
            print(f"studio idle: server RSS {proc_mib(pids['server']):.0f} MiB, simulator "
                  f"{proc_mib(pids['simulator']):.0f} MiB")
            for what, attack in cases:
                for pid in pids.values():
                    Path(f"/proc/{pid}/clear_refs").write_text("5")
                t0 = time.perf_counter()
                did = attack()
                took = time.perf_counter() - t0
                t1 = time.perf_counter()
                code = st.request("api/characteristic", _studio_condition())[0]
                page = time.perf_counter() - t1
                print(f"studio: {what:42s} {did} ({took:.1f} s); a page then {code} in "
                      f"{page:.2f} s; peak RSS server {proc_mib(pids['server'], 'VmHWM'):.0f} "
                      f"MiB, simulator {proc_mib(pids['simulator'], 'VmHWM'):.0f} MiB")
        finally:
            stop_studio(st)


#: [compute]'s run in part 7: a 2 x 2 display on one controller
COMPUTE_CONFIG = """state_dir = "state"
[site]
latitude = 48.1
longitude = 11.6
timezone = "Europe/Berlin"
[display]
rows = 2
cols = 2
[[controllers]]
port = "/dev/null"
[[viewpoints]]
h_cm = 170
d_m = 2
[light]
inbox = "inbox"
""" + SMALL_RUN


def compute() -> None:
    """Part 7: the compute offload's attacks against the daemon's Dask client; each row: what
    the run did, its seconds, this process's peak RSS growth, and whether the hostile
    command ran (its mark file)."""
    from datetime import UTC, datetime

    from grassd.daemon.compute.remote import RemoteCalibrator, calibrate_on_worker
    from grassd.daemon.core.config.settings import parse_config
    from grassd.rigs.dask_cluster import ClusterUnavailable, DaskCluster, SiteCA
    from grassd.sim.hdri import default_site_hdri
    from grassd.sim.light_input import LightInput

    light = LightInput(hdri=default_site_hdri(), ambient_lux=6000.0, sun_lux=20000.0,
                       timestamp=datetime(2026, 6, 21, 10, tzinfo=UTC))
    with tempfile.TemporaryDirectory(prefix="grassd-bench-compute-") as tmp:
        d = Path(tmp)
        cfg = parse_config(COMPUTE_CONFIG, base_dir=d)

        def row(what: str, mark: Path, fn: Callable[[], object]) -> None:
            raised, seconds, growth = peak_rss_growth(fn)
            did = ("ran" if raised is None
                   else f"{type(raised).__name__}: {str(raised).splitlines()[0][:110]}")
            ran = mark.read_text().split() if mark.exists() else []
            print(f"compute: {what:44s} {did} ({seconds:.1f} s); peak RSS +{growth / 2**20:.0f}"
                  f" MiB; hostile command ran in {len(ran)} process(es)", flush=True)

        def daemon_run(cluster: DaskCluster) -> Callable[[], object]:
            remote = RemoteCalibrator(cfg.replace(compute=cluster.compute(worker_wait_s=10.0)))
            return lambda: remote.run(light)

        try:
            import distributed  # configures its loggers: quieted after
            logging.getLogger(distributed.__name__).setLevel(logging.CRITICAL + 1)  # its traces
            with DaskCluster(d / "stranger") as cluster:
                mark = d / "stranger.ran"
                cert, key = SiteCA(d / "stranger-ca", "stranger-ca").issue("stranger")
                cluster.start_worker("stranger", tls_args=[
                    "--tls-ca-file", str(cluster.ca.ca_file), "--tls-cert", str(cert),
                    "--tls-key", str(key)], extra=("--preload", cluster.hostile_preload(mark)))
                row("a worker of another CA", mark, daemon_run(cluster))
            with DaskCluster(d / "hostile") as cluster:
                mark = d / "hostile.ran"
                cluster.add_worker("hostile", extra=("--preload", cluster.hostile_preload(mark)))
                row("a worker with a certificate, pickle answer", mark, daemon_run(cluster))
            with DaskCluster(d / "honest", cache_dir=str(d / "cache")) as cluster:
                cluster.add_worker("honest")
                row("an honest worker", d / "honest.ran", daemon_run(cluster))
            with DaskCluster(d / "plain", tls=False) as cluster:
                mark = d / "plain.ran"
                cluster.add_worker("hostile", extra=("--preload", cluster.hostile_preload(mark)))

                def defaults() -> object:
                    with distributed.Client(cluster.address, timeout=30,
                                            set_as_default=False) as client:
                        return client.submit(calibrate_on_worker, b"", pure=False).result(60)
                row("the same on tcp://, Dask's default client", mark, defaults)
        except ClusterUnavailable as exc:
            print(f"compute: skipped ({exc})")


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--bundles", type=int, default=1000)
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--only", nargs="+", choices=PARTS, default=PARTS,
                    help="run only these parts (default: all)")
    args = ap.parse_args(argv if argv is not None else [])
    run: dict[str, Callable[[], None]] = {
        "attacks": attacks, "camera": camera, "fuzz": lambda: fuzz(args.bundles, args.seed),
        "decoders": decoders, "studio": studio, "compute": compute}
    for part in args.only:
        run[part]()


#: The parts, in the order they run (the module docstring numbers them).
PARTS = ["attacks", "camera", "fuzz", "decoders", "studio", "compute"]


if __name__ == "__main__":
    main(sys.argv[1:])
