"""A measuring camera that lies is refused: it answers with the shots out of order, with old
photos (an honest earlier measurement's, in its order), or with a photo of another display
state. Each measurement runs the real path (``Service.measure``: patterns on the simulated
controllers over ptys, the simulated camera over HTTP on 127.0.0.1, the fit, the checks), is
refused with the check that caught it, and pushes nothing: the correction, the active tables
and the controllers' tables stay as the honest measurement left them.

The site is made once for the module (the display's hidden variation, the controllers, the
camera's set-up) with one honest measurement, which must be accepted: the checks are not
simply refusing everything."""

from __future__ import annotations

import json
import os
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
import pytest
from daemon_harness import write_config

from grassd.daemon.cli.features import daemon_features
from grassd.daemon.core.config.settings import load_config, load_default_config
from grassd.daemon.core.runtime.service import Service
from grassd.daemon.core.store.history import History
from grassd.daemon.core.store.layout import StateLayout
from grassd.daemon.measure.cli import simulated_setup, start_measuring_camera
from grassd.daemon.measure.evidence import Refusal
from grassd.firmware_proto.client import ControllerClient
from grassd.rigs.simulated_site import SimulatedHardware

pytestmark = pytest.mark.long

SECRET = Path(__file__).resolve().parents[2] / "data" / "measure" / "secret_variation.toml"
MEASURE = """[measure]
camera = "{url}"
pattern_timeout_s = 30
settle_s = 10.0
samples = 256
layouts = 1
patterns = 4
keep_photos = 2
"""


class Site:
    """The measured site: simulated hardware, display, camera, config, and what the honest
    measurement left (its report, the display states it photographed, in order)."""

    def __init__(self, root: Path) -> None:
        self.sim = SimulatedHardware(load_default_config(), root / "hw", lux=2500.0)
        cfg = self.sim.start()
        self.display, self.camera = start_measuring_camera(self.sim, cfg, str(SECRET), 2500.0,
                                                           samples=256)
        self.path = write_config(root / "grassd.toml", root / "state", cfg,
                                 extra=MEASURE.format(url=self.camera.url))
        self.cfg = load_config(self.path)
        self.layout = StateLayout(self.cfg.state_dir)
        first = self._service_do(lambda svc: svc.one_shot())
        assert first.status == "ok", first
        simulated_setup(self.cfg, self.display, self.camera.url, 2500.0)
        self.honest_states: list[np.ndarray] = []
        self.camera.scene_source = self._recording
        self.honest = self.measure()
        self.camera.scene_source = self.display.scene

    def _recording(self) -> np.ndarray:
        self.honest_states.append(np.array(self.sim.positions_um(), dtype=np.float64))
        return self.display.scene()

    def _service_do(self, what: Callable[[Service], dict]) -> dict:
        svc = Service(self.cfg, features=daemon_features())
        try:
            return what(svc)
        finally:
            svc.shutdown()

    def measure(self) -> dict:
        """One measurement through the daemon's service, as ``grassd measure --now``."""
        return self._service_do(lambda svc: svc.features.get("measure").now(svc))

    def photo_of(self, positions_um: np.ndarray) -> np.ndarray:
        """The camera's view of the display with its grass at ``positions_um`` (N,)."""
        real = self.display.positions_um
        self.display.positions_um = lambda: positions_um
        try:
            return self.display.scene()
        finally:
            self.display.positions_um = real

    def pushed(self) -> tuple:
        """What is active: the correction file, the history's current table, the controllers'
        table ids, and the runs made by measurements."""
        ids = []
        for c in self.cfg.controllers:
            with ControllerClient(c.port) as client:
                ids.append(client.read_status(c.address).table_id)
        history = History(self.layout.db)
        return (self.layout.correction.read_bytes(), history.current_table().id, tuple(ids),
                [r.id for r in history.runs(50) if r.trigger == "measure"])

    def stop(self) -> None:
        self.camera.stop()
        self.sim.stop()


@pytest.fixture(scope="module")
def site(tmp_path_factory) -> Iterator[Site]:
    s = Site(tmp_path_factory.mktemp("hostile"))
    try:
        yield s
    finally:
        s.stop()


def test_the_honest_measurement_is_accepted_and_pushed(site):
    report = site.honest
    assert report["status"] == "ok", report.get("error")
    ev = report["evidence"]
    print("honest evidence:", json.dumps({k: ev[k] for k in ("noise_lab", "fit_rms_lab")}),
          "shots", max(ev["shot_rms_lab"].values()))
    assert ev["accepted"] and ev["findings"] == []
    assert report["tables"]["status"] == "ok" and all(report["tables"]["pushed"])
    assert len(ev["order"]) == len(site.honest_states)  # every photo taken is judged


def _refused(site: Site, source: Callable[[], np.ndarray]) -> dict:
    before = site.pushed()
    site.camera.scene_source = source
    try:
        report = site.measure()
    finally:
        site.camera.scene_source = site.display.scene
    ev = report.get("evidence", {})
    print(report["status"], report.get("error"), {k: ev.get(k) for k in (
        "noise_lab", "photo_noise_lab", "fit_rms_lab", "at_bound", "shot_rms_lab")})
    assert report["status"] == "refused", report.get("error")
    assert report["tables"]["run_id"] is None
    assert site.pushed() == before  # nothing pushed, nothing kept
    assert not any(c.in_pattern for bus in site.sim.buses for c in bus.controllers)
    saved = json.loads(Path(report["report"]).read_text())
    assert saved["status"] == "refused" and not saved["evidence"]["accepted"]
    page = Path(report["report"]).with_suffix(".html").read_text()
    assert "Refused" in page and saved["evidence"]["findings"][0]["kind"] in page
    return report


def _kinds(report: dict) -> set[Refusal]:
    return {Refusal(f["kind"]) for f in report["evidence"]["findings"]}


#: what refuses photos that are not of the state asked: the display not found in the photos
#: of its shortest and longest grass (when those are wrong), else the shots named
NOT_OF_THE_STATE = {Refusal.SHOT_MISMATCH, Refusal.DISPLAY_NOT_FOUND}


def test_shots_answered_out_of_order_are_refused(site):
    """Each shot answered with the photo of the state the display showed for the shot before
    (the order is drawn anew in each measurement: the camera cannot answer ahead)."""
    last: list[np.ndarray] = []

    def one_behind() -> np.ndarray:
        now = np.array(site.sim.positions_um(), dtype=np.float64)
        shown = last[-1] if last else now
        last.append(now)
        return site.photo_of(shown)

    report = _refused(site, one_behind)
    assert _kinds(report) & NOT_OF_THE_STATE, report["evidence"]


def test_old_photos_are_refused(site):
    """The honest measurement's photos, answered again in the order they were taken."""
    old = iter(site.honest_states)
    report = _refused(site, lambda: site.photo_of(next(old)))
    assert _kinds(report) & NOT_OF_THE_STATE, report["evidence"]


def test_a_photo_of_another_display_state_is_refused(site):
    """One photo (the fourth) shows the pixels alternately at their shortest and longest
    grass, a state no shot asked for; the others are honest: that photo is named."""
    calls: list[int] = []
    d = site.cfg.display
    checkerboard = np.indices((d.rows, d.cols)).sum(axis=0).ravel() % 2 * d.green_max_mm * 1000.0

    def one_wrong() -> np.ndarray:
        calls.append(1)
        if len(calls) == 4:
            return site.photo_of(checkerboard)
        return site.display.scene()

    report = _refused(site, one_wrong)
    ev = report["evidence"]
    wrong = ev["order"][3]
    if wrong in ("short", "long"):  # the display is located from these two
        assert _kinds(report) & NOT_OF_THE_STATE, ev
        return
    [mismatch] = [f for f in ev["findings"] if f["kind"] == Refusal.SHOT_MISMATCH.value]
    # that photo alone is named: the honest shots its pull on the fit took past the limit
    # agree with the fit made without it
    rms = ev["shot_rms_lab"]
    assert mismatch["shots"] == [wrong] and max(rms, key=rms.get) == wrong, (mismatch, rms)


def test_verification_photos_that_disagree_with_the_correction_are_refused(site):
    """The photos before the correction are honest; each photo after it shows the state the
    display held for the shot before (the order of the verification shots is drawn too)."""
    n_before = len(site.honest_states) - 5  # the five verification shots come last
    calls: list[np.ndarray] = []

    def after_one_behind() -> np.ndarray:
        calls.append(np.array(site.sim.positions_um(), dtype=np.float64))
        if len(calls) <= n_before:
            return site.display.scene()
        return site.photo_of(calls[-2])

    report = _refused(site, after_one_behind)
    ev = report["evidence"]
    kinds = _kinds(report)  # the honest photos before pass; the uniformity may fail too
    assert Refusal.VERIFICATION in kinds and kinds <= {Refusal.VERIFICATION,
                                                       Refusal.NOT_MORE_UNIFORM}, ev["findings"]
    [finding] = [f for f in ev["findings"] if f["kind"] == Refusal.VERIFICATION.value]
    assert set(finding["shots"]) <= {x for x in ev["order"] if x.startswith("after-")}
    assert len(finding["shots"]) >= 4, finding  # at most one neighbour could look alike


def test_a_raw_declaring_a_huge_sensor_fails_the_measurement_within_memory(site, tmp_path):
    """A camera answering every shot with a 20 KiB DNG that declares 16384 x 8192
    photosites: the measurement fails from the header, before a pixel is unpacked, writes its
    report and pushes nothing (it peaked at 3168 MiB, and a kill under MemoryMax wrote no
    report, so the measurement was due again at once)."""
    from grassd.rigs.hostile_decodes import dng_declaring, small_dng
    from grassd.rigs.peak_memory import proc_mib

    size = dng_declaring(small_dng(tmp_path / "small.dng"), tmp_path / "huge.dng", 16384, 8192)
    before = site.pushed()
    site.camera.faults.raw_file = (tmp_path / "huge.dng").read_bytes()
    Path("/proc/self/clear_refs").write_text("5")  # VmHWM from here
    rss = proc_mib(os.getpid(), "VmRSS")
    try:
        report = site.measure()
    finally:
        site.camera.faults.clear()
    growth = proc_mib(os.getpid(), "VmHWM") - rss
    print(f"{size / 2**20:.2f} MiB DNG: {report['status']}: {report.get('error')}; "
          f"peak RSS +{growth:.0f} MiB")
    assert report["status"] == "failed" and "16384" in report["error"], report.get("error")
    assert growth < 400
    assert report.get("tables", {}).get("run_id") is None and site.pushed() == before
    assert not any(c.in_pattern for bus in site.sim.buses for c in bus.controllers)
    assert json.loads(Path(report["report"]).read_text())["status"] == "failed"


def test_only_the_newest_measurements_keep_their_photos(site):
    """After the module's measurements (each took photos), the photos of the newest two
    (``keep_photos``) are left, and every report."""
    reports = [p.stem for p in site.layout.measurement_reports()]
    folders = sorted(p.name for p in site.layout.measure.iterdir() if p.is_dir())
    assert folders == reports[-2:], (folders, reports)
    assert all(any(site.layout.measure.joinpath(m).glob("*.dng")) for m in folders)
