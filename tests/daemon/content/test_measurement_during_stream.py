"""A measurement while a live sACN source streams: the daemon's own ``measure()`` on simulated
controllers (the Python model on ptys) with ``[content]`` on and the ``sacn`` library's sender
changing every pixel's level 30 times a second. Before it, frames reach the controllers at
their steady rate; during it no frame is shown (the output is held, the controllers show only
the measurement's patterns and otherwise keep the last frame shown before it); after it the
stream resumes by itself (its newest frame within a second, at least 90 % of the steady rate),
and the daemon's memory grew at most 16 MiB. The measurement's outcome is whatever it is: the
camera photographs the site panorama, not the display."""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field

import numpy as np
import pytest
from daemon_harness import service, write_config

from grassd.daemon.core.calibration.display_model import controller_pixels
from grassd.daemon.core.store.atomic import atomic_write_json
from grassd.daemon.core.store.layout import StateLayout
from grassd.daemon.measure.camera_chain import Exposure, MeasureSetup
from grassd.rigs.simulated_camera import start_site_camera

pytestmark = pytest.mark.long

FPS = 30
#: seconds of stream over which a rate is counted
WINDOW_S = 2.0
RSS_GROWTH_MIB = 16.0
#: measurements before the one watched (their one-off allocations are not growth)
WARM_UP = 5


def _playback(svc):
    """The service's content playback now (None: none)."""
    return svc.features.get("content").playback


def _rss_mib() -> float:
    """This process's resident set (MiB): the in-process daemon's."""
    for line in open("/proc/self/status"):
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024.0
    raise AssertionError("no VmRSS in /proc/self/status")


class _Stream:
    """The sACN sender's universe 1 gets new levels for every pixel ``FPS`` times a second;
    keeps (monotonic time, levels) of each frame set."""

    def __init__(self, sender, n: int) -> None:
        self.sender, self.n = sender, n
        self.sent: list[tuple[float, np.ndarray]] = []
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        step = 0
        while not self.stop.wait(1.0 / FPS):
            levels = ((np.arange(self.n) * 13 + step * 7) % 251 + 2).astype(np.uint8)
            self.sender[1].dmx_data = tuple(int(v) for v in levels)
            self.sent.append((time.monotonic(), levels))
            step += 1

    def since(self, t: float) -> list[np.ndarray]:
        return [lv for at, lv in list(self.sent) if at >= t]

    def __enter__(self) -> _Stream:
        self.thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop.set()
        self.thread.join(5)


@dataclass
class _Sample:
    """The output's state read before and after the motors' targets: (held, frames shown)
    each time, whether a controller was in a pattern, every display pixel's target (um)."""

    before: tuple[bool, int]
    pattern: bool
    targets: np.ndarray
    after: tuple[bool, int]


@dataclass
class _Watch:
    """What the model controllers' motors are asked to do while the measurement runs."""

    sim: object
    svc: object
    samples: list[_Sample] = field(default_factory=list)
    stop: threading.Event = field(default_factory=threading.Event)
    #: samples are kept while set
    recording: threading.Event = field(default_factory=threading.Event)

    def targets(self) -> tuple[bool, np.ndarray]:
        cfg = self.svc.cfg
        n = cfg.display.pixel_count
        ports = list(dict.fromkeys(c.port for c in cfg.controllers))
        out, pattern = np.zeros(n), False
        for c, pix in zip(cfg.controllers, controller_pixels(cfg.controllers, n), strict=True):
            bus = self.sim.buses[ports.index(c.port)]
            ctrl = next(x for x in bus.controllers if x.config.address == c.address)
            pattern |= ctrl.in_pattern
            out[pix] = ctrl.targets_um()[:len(pix)]
        return pattern, out

    def output(self) -> tuple[bool, int]:
        out = _playback(self.svc).status().output
        return out["held"], out["frames_shown"]

    def run(self) -> None:
        while not self.stop.wait(0.02):
            before = self.output()
            pattern, targets = self.targets()
            sample = _Sample(before, pattern, targets, self.output())
            if self.recording.is_set():
                self.samples.append(sample)


def _shown(svc) -> int:
    return _playback(svc).status().output["frames_shown"]


def _rate(svc, seconds: float) -> float:
    """Frames shown per second over the next ``seconds``."""
    a, t0 = _shown(svc), time.monotonic()
    time.sleep(seconds)
    return (_shown(svc) - a) / (time.monotonic() - t0)


def test_a_measurement_during_a_live_stream_holds_it_and_gives_it_back(
        tmp_path, hw, ports, sacn_senders):
    sim, cfg = hw
    camera = start_site_camera(sim)
    path = write_config(tmp_path / "grassd.toml", tmp_path / "state", cfg, extra=(
        f'[measure]\ncamera = "{camera.url}"\npattern_timeout_s = 600\nsettle_s = 10\n'
        f"patterns = 4\n[content]\nenabled = true\nfps = {FPS}\nhold_s = 30\n"
        f"[content.sacn]\nport = {ports[0]}\n[content.artnet]\nport = {ports[1]}\n"))
    setup = MeasureSetup((1.0, 1.0, 1.0, 1.0), 1.0, Exposure(0.01, 100, 5.6), 2500.0,
                         ((1.0, 0, 0), (0, 1.0, 0), (0, 0, 1.0)), "spydercheckr-24", "x.dng",
                         "2026-11-27T00:00:00+00:00")
    atomic_write_json(StateLayout(tmp_path / "state").measure_setup, setup.to_json())
    svc = service(path)
    watch = _Watch(sim, svc)
    try:
        table = np.rint(np.linspace(0, 20000, 256)).astype(np.uint16)
        assert all(r.ok for r in svc.fleet.push(table, 1))
        svc._init_renderer()  # what run() does before serving: not counted as growth
        svc.features.restart(svc, None)  # ... once its control socket serves
        n = svc.cfg.display.pixel_count
        with _Stream(sacn_senders(ports[0], fps=FPS), n) as stream:
            time.sleep(1.0)
            watcher = threading.Thread(target=watch.run, daemon=True)
            watcher.start()  # (the watching thread runs through the warm-up too)
            # the daemon's first measurements allocate its calibrator's and renderer's
            # buffers (and the allocator's per-thread arenas) once; the growth counted is
            # that over the one after them
            for _ in range(WARM_UP):
                warm = svc.features.get("measure").now(svc)
                camera.files.clear()  # the simulated camera's card, not the daemon's memory
                print(f"warm-up measurement: {warm['status']}, RSS {_rss_mib():.1f} MiB")
            rss0 = _rss_mib()
            steady = _rate(svc, WINDOW_S)
            before = _rate(svc, WINDOW_S)
            print(f"before: {steady:.1f} then {before:.1f} frames/s shown")
            watch.recording.set()
            started = time.monotonic()
            report = svc.features.get("measure").now(svc)
            ended = time.monotonic()
            watch.recording.clear()
            print(f"measurement: {report['status']} in {ended - started:.1f} s: "
                  f"{report.get('error')}")
            sent_during = len(stream.since(started)) - len(stream.since(ended))
            # after it: the newest frame within a second, then the steady rate again
            deadline = ended + 1.0
            while True:
                in_pattern, got = watch.targets()
                fresh = stream.since(ended)
                if not in_pattern and any(np.array_equal(got, table[lv]) for lv in fresh):
                    break
                assert time.monotonic() < deadline, "the stream did not resume within 1 s"
                time.sleep(0.01)
            resumed = time.monotonic() - ended
            after = _rate(svc, WINDOW_S)
            camera.files.clear()
            rss1 = _rss_mib()
            watch.stop.set()
            watcher.join(5)
        print(f"after: newest frame shown {resumed * 1e3:.0f} ms after the measurement, "
              f"{after:.1f} frames/s; RSS {rss0:.1f} -> {rss1:.1f} MiB")
    finally:
        watch.stop.set()
        svc.shutdown()
        camera.stop()

    assert steady >= 0.5 * FPS and before >= 0.9 * steady, (steady, before)
    assert report["status"] in ("ok", "refused", "failed"), report
    assert sent_during >= FPS, sent_during  # the source kept streaming meanwhile
    # during it: held, and no frame shown but the one in flight when the hold was asked for
    held = [x for x in watch.samples if x.before[0] and x.after[0]]
    assert held, "the measurement never held the display"
    counts = sorted({x.before[1] for x in held} | {x.after[1] for x in held})
    assert len(counts) <= 2 and counts[-1] - counts[0] <= 1, counts
    quiet = [x for x in held if x.before[1] == x.after[1] == counts[-1]]
    # the motors: the measurement's patterns, else the last frame shown before it
    patterns = [x.targets for x in quiet if x.pattern]
    content = [x.targets for x in quiet if not x.pattern]
    assert patterns, "no pattern seen while held"
    assert content, "no sample of content while held"
    kept = content[0]
    assert any(np.array_equal(kept, table[lv]) for _, lv in stream.sent)
    for t in content:
        np.testing.assert_array_equal(t, kept)
    frames = [table[lv] for lv in stream.since(started)]
    for t in patterns:
        assert not any(np.array_equal(t, f) for f in frames)
    assert after >= 0.9 * steady, (after, steady)
    assert rss1 - rss0 <= RSS_GROWTH_MIB, (rss0, rss1)
