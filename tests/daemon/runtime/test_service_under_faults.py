"""The service under faults: a full or unwritable state disk, an unreadable inbox, failing
rejections and reads, a controller whose pixel count changed, status asked while bundles wait.

Real parts only: simulated controllers on ptys (SimulatedHardware), the real renderer at tiny
sample counts, a real tmpfs that fills up (when the tests run as root and may mount).
"""

from __future__ import annotations

import contextlib
import os
import shutil
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from daemon_harness import DISPLAY_2X2 as BASE
from daemon_harness import POLICY, full, service, tmpfs, wait_for, write_config
from daemon_harness import drop as rdrop
from daemon_harness import drop_midsummer as drop

from grassd.daemon.core.calibration.calibrate import init_backend
from grassd.daemon.core.config.settings import parse_config
from grassd.daemon.core.errors import DaemonError, StateDirLocked
from grassd.daemon.core.hardware.fleet import Fleet, table_checksum
from grassd.daemon.core.runtime.bundle_pipeline import Deferred
from grassd.daemon.core.runtime.service import Service, collect_status
from grassd.daemon.core.runtime.statelock import StateLock
from grassd.rigs.simulated_site import SimLuxSensor, SimulatedHardware

PIXEL = '[tables]\ngranularity = "pixel"\ncheck_groups = 0\n'


def _pixel_config(tmp_path, first: str, second: str):
    text = BASE.replace('pixels = "0-1"', f'pixels = "{first}"').replace(
        'pixels = "2-3"', f'pixels = "{second}"')
    return parse_config(text + PIXEL, base_dir=tmp_path)


def _run_bundle(svc: Service, name: str, lux: float = 8000.0) -> dict:
    drop(svc.cfg.light.inbox, name, lux)
    [b] = svc.inbox.poll()
    return svc.process_bundle(b)


def _passes_until(svc: Service, cond, what: str, timeout: float = 120.0) -> None:
    """Run main-loop passes of ``svc`` (as its run loop does) until ``cond()`` holds. The
    timeout only ends a test that hangs; it is no speed target."""
    def done() -> bool:
        if cond():
            return True
        svc.main_loop_pass()
        return False

    wait_for(done, timeout, what)


@pytest.fixture
def resized(tmp_path):
    """A run with per-pixel tables on two controllers driving 2 + 2 pixels; then the same
    ports and state with the controllers re-flashed for 1 + 3 pixels (a config change).
    Yields (first run's result, service, simulated hardware) of the second start."""
    hw = tmp_path / "hw"
    sim = SimulatedHardware(_pixel_config(tmp_path, "0-1", "2-3"), hw)
    svc = Service(sim.start(), policy=POLICY)
    try:
        init_backend(svc.cfg)
        first = _run_bundle(svc, "b1")
        assert first.status == "ok", first
    finally:
        svc.shutdown()
        sim.stop()
    shutil.rmtree(hw / "eeprom")  # re-flashed controllers with the new pixel counts
    sim = SimulatedHardware(_pixel_config(tmp_path, "0-0", "1-3"), hw)
    svc = Service(sim.start(), policy=POLICY)
    yield first, svc, sim
    svc.shutdown()
    sim.stop()


def test_pixel_tables_after_a_controllers_pixel_count_changed(resized):
    """A controller that drives 3 pixels instead of 2 after a config change (restart with
    the same ports and state): the next run must not fail for ever comparing its new (3, 256)
    table with its old (2, 256) one, and gets its new table."""
    first, svc, sim = resized
    n0, n1 = (c.name for c in svc.cfg.controllers)
    assert set(svc.history.run_tables(first.run_id)) == {n0, n1}  # same names
    out = _run_bundle(svc, "b2", 8100.0)
    assert out.status == "ok", out
    own = svc.history.run_tables(out.run_id)
    assert own[n0].lengths_um.shape == (1, 256) and own[n1].lengths_um.shape == (3, 256)
    for c, bus in zip(svc.cfg.controllers, sim.buses, strict=True):
        active = bus.controllers[0].active_table()
        np.testing.assert_array_equal(active, own[c.name].lengths_um)
        assert table_checksum(active) == out.committed.controller_crcs[c.name]


def test_reconcile_after_a_pixel_count_change_pushes_the_display_wide_table(resized):
    """Until the next run, a controller whose pixel count changed cannot take its old
    (2, 256) tables (it refuses them at every reconcile and stays out of sync): it gets the
    run's display-wide table, as one added to the config afterwards does, and status agrees."""
    first, svc, _ = resized
    reports = svc.reconcile()
    assert [(r.ok, r.table_id) for r in reports] == [(True, first.run_id)] * 2, reports
    assert {r.table_crc for r in reports} == {first.committed.table_crc}  # display-wide table
    st = collect_status(svc.history, svc.cfg).to_json()
    assert st["health"] == "ok", st["controllers"]

# --------------------------------------------------------------------------- a full state disk


def test_claimed_bundles_survive_a_full_state_disk(tmp_path, hw):
    """Two bundles claimed by one poll when the state disk fills up: the database write of the
    first fails. Neither may be stranded in processing/ until the next restart: both wait
    (status) and run once space is back."""
    _, cfg = hw
    with tmpfs(tmp_path / "state") as state:
        conf = write_config(tmp_path / "g.toml", state, cfg)
        svc = service(conf, retry_s=0.3, reconcile_s=1e9)
        try:
            inbox = svc.cfg.light.inbox
            rdrop(inbox, "b1", lux=1000.0)
            rdrop(inbox, "b2", lux=1200.0)
            claimed = svc.inbox.poll()
            assert len(claimed) == 2
            with full(state):
                svc.tick(claimed)  # must not raise: the daemon survives, the bundles wait
                assert svc.inbox.counts()["processing"] == 2
                st = svc.status().to_json()
                assert sorted(w["bundle"] for w in st["waiting_bundles"]) == ["b1", "b2"]
                assert "full" in st["last_error"]
            _passes_until(svc, lambda: svc.inbox.counts()["archive"] == 2,
                          "both bundles archived once space is back")
            assert svc.inbox.counts() == {"inbox": 0, "processing": 0, "archive": 2,
                                          "rejected": 0}
            assert svc.status().to_json()["waiting_bundles"] == []
            assert [r.status for r in svc.history.runs(5)].count("ok") == 2
        finally:
            svc.shutdown()


def test_calibrate_request_is_answered_when_its_run_hits_a_full_disk(tmp_path, hw):
    """`grassd calibrate --now --wait` while the state disk is full: the client gets the
    failure once the main-loop pass that ran it returns, not a hang until its timeout (it held
    a control-socket slot). The request may wait an hour (the default); the answer must be
    there when the pass returned (the join's deadline only ends a test that hangs)."""
    _, cfg = hw
    with tmpfs(tmp_path / "state") as state:
        conf = write_config(tmp_path / "g.toml", state, cfg)
        svc = service(conf, reconcile_s=1e9)
        try:
            answers: list[dict] = []
            with full(state):
                t = threading.Thread(target=lambda: answers.append(svc.handle_request(
                    {"cmd": "calibrate", "wait": True, "timeout_s": 3600})), daemon=True)
                t.start()
                wait_for(lambda: not svc.requests.empty() or not t.is_alive(), 60,
                         "the request in the main loop's queue")
                svc.main_loop_pass()  # runs the request; its run fails on the full disk
                t.join(60)
            assert not t.is_alive(), "the client still waits after the pass that ran its run"
            [ans] = answers
            assert ans["ok"] and ans["run"]["status"] == "failed", ans
            assert "full" in ans["run"]["error"]
        finally:
            svc.shutdown()


def test_unwritable_state_dir_is_one_line_user_error(tmp_path):
    """The state lock is the first thing `grassd run` / `calibrate --now` writes: a read-only
    (or foreign) state directory must give a DaemonError naming the path and the fix (the CLI
    prints one line, exit 2), not a raw OSError traceback."""
    state = tmp_path / "state"
    state.mkdir()
    if os.geteuid() == 0:
        if subprocess.run(["mount", "-t", "tmpfs", "-o", "ro,size=1m", "tmpfs", str(state)],
                          capture_output=True).returncode != 0:
            pytest.skip("root without mount(8): cannot make a directory unwritable")
        why = "read-only"
    else:
        os.chmod(state, 0o555)
        why = "permission denied"
    try:
        with pytest.raises(DaemonError) as err:
            StateLock(state).acquire()
        msg = str(err.value)
        assert str(state / "grassd.lock") in msg and why in msg.lower(), msg
        assert "\n" not in msg
    finally:
        if os.geteuid() == 0:
            subprocess.run(["umount", "-l", str(state)], check=True)
        else:
            os.chmod(state, 0o755)


def test_bundle_claimed_before_a_failing_rejection_is_processed(tmp_path, hw):
    """One poll claims a good bundle, then fails to reject a bad one (rejected/ read-only:
    the move raises): the good bundle must still be processed, not stranded in processing/
    until the next restart."""
    _, cfg = hw
    conf = write_config(tmp_path / "g.toml", tmp_path / "state", cfg)
    svc = service(conf, reconcile_s=1e9)
    svc.inbox.rejected.mkdir(parents=True, exist_ok=True)
    try:
        with readonly(svc.inbox.rejected):
            inbox = svc.cfg.light.inbox
            rdrop(inbox, "a1", lux=1000.0)
            (inbox / ".b2").mkdir()
            (inbox / ".b2" / "manifest.toml").write_text("this is = = not toml\n")
            os.rename(inbox / ".b2", inbox / "b2")
            for _ in range(3):
                svc.main_loop_pass()
            assert svc.inbox.counts()["archive"] == 1, svc.inbox.counts()
            assert svc.history.current_table() is not None
    finally:
        svc.shutdown()



def test_full_state_disk_at_start_is_a_user_error_and_leaks_no_lock(tmp_path, hw):
    """Starting on a full state disk: the PID note in grassd.lock cannot be written. That
    note is informational: the flock is taken all the same (and released by release()), and
    the start fails, if at all, with a one-line DaemonError (the database cannot open its
    WAL), not a raw ENOSPC traceback with the lock left held by the failed attempt."""
    _, cfg = hw
    with tmpfs(tmp_path / "state") as state:
        conf = write_config(tmp_path / "g.toml", state, cfg)
        service(conf).shutdown()  # database and (empty) lock file exist
        with full(state):
            lock = StateLock(state).acquire()
            assert lock.held
            with pytest.raises(StateDirLocked):
                StateLock(state).acquire()  # a second process is still kept out
            lock.release()
            StateLock(state).acquire().release()  # and it was released for real
            with pytest.raises(DaemonError, match="state.db"):
                service(conf)
            StateLock(state).acquire().release()  # the failed start left no lock behind


def test_unreadable_inbox_does_not_stop_reconcile_and_requests(tmp_path, hw):
    """The inbox is a symlink to an upload share that goes away (dangling link: every poll
    fails). The daemon must still serve what does not need the inbox: a controller that
    lost its table is reconciled and a queued calibration request runs."""
    sim, cfg = hw
    share = tmp_path / "share"
    share.mkdir()
    conf = write_config(tmp_path / "g.toml", tmp_path / "state", cfg)
    (tmp_path / "state").mkdir()
    (tmp_path / "state" / "inbox").symlink_to(share)
    svc = service(conf, reconcile_s=0.0)
    try:
        rdrop(share, "b1", lux=1000.0)
        svc.main_loop_pass()
        cur = svc.history.current_table()
        assert cur is not None and svc.inbox.counts()["archive"] == 1
        shutil.rmtree(share)  # the share is gone
        with pytest.raises(OSError):
            svc.inbox.poll()
        dev = sim.buses[0].controllers[0]
        other = np.linspace(0, 15000, 256).astype(np.uint16)
        with Fleet(svc.cfg.controllers[:1], policy=POLICY) as fleet:  # someone else's table
            [r] = fleet.push(other, table_id=999)
            assert r.ok
        assert table_checksum(dev.active_table()) != cur.table_crc
        assert svc.handle_request({"cmd": "calibrate"})["ok"]
        for _ in range(3):
            svc.main_loop_pass()
        assert table_checksum(dev.active_table()) == svc.history.current_table().table_crc
        assert svc.requests.empty()
        assert svc.history.runs(1)[0].trigger == "request"
        assert "inbox" in (svc.status().to_json()["last_error"] or "")
    finally:
        svc.shutdown()


@contextlib.contextmanager
def readonly(d: Path):
    """Make directory ``d`` refuse writes: a read-only bind mount (root), else mode 0555."""
    if os.geteuid() == 0:
        if subprocess.run(["mount", "--bind", str(d), str(d)],
                          capture_output=True).returncode != 0:
            pytest.skip("mount --bind not permitted")
        try:
            subprocess.run(["mount", "-o", "remount,bind,ro", str(d)], check=True)
            yield
        finally:
            subprocess.run(["umount", "-l", str(d)], check=True)
    else:
        os.chmod(d, 0o555)
        try:
            yield
        finally:
            os.chmod(d, 0o755)


def test_an_error_wait_is_not_pulled_onto_the_lux_deadline(tmp_path, hw):
    """The lux wait's deadline caps only lux waits (their last try falls on it). A bundle that
    then waits after an error (an unwritable report) backs off from its own delay: the old
    code pulled every retry onto the still-future lux deadline, so a run that failed just
    before it was retried at once (a third run within a few ms: a flaky test under load)."""
    sim, cfg = hw
    conf = write_config(tmp_path / "g.toml", tmp_path / "state", cfg)
    # delays of 30 s and up and a lux deadline 50 s ahead: every time read below brackets a
    # call (t0 before, t1 after), so the checks hold however slowly the machine runs them
    svc = service(conf, retry_s=30.0, retry_max_s=1000.0, reconcile_s=1e9)
    try:
        rdrop(svc.cfg.light.inbox, "b", lux=None)
        [b] = svc.inbox.poll()

        def defer(reason: str, **kw) -> tuple[float, float]:
            t0 = time.monotonic()
            svc._defer(b, reason, **kw)
            return t0, time.monotonic()

        t0, t1 = defer("waiting for the lux sensor: down", limit_s=50.0)
        d = svc.deferred[b.hash]
        assert t0 + 30 <= d.retry_at <= t1 + 30
        assert d.give_up_at - d.retry_at == pytest.approx(20)  # deadline 50 s after the wait
        t0, t1 = defer("cannot write the report", error=True)  # delay 60 s > the deadline
        assert t0 + 60 <= d.retry_at <= t1 + 60  # not pulled onto the deadline (< t0 + 50)
        t0, t1 = defer("cannot write the report", error=True)  # delay 120 s
        assert t0 + 120 <= d.retry_at <= t1 + 120
        defer("waiting for the lux sensor: down", limit_s=50.0)  # a lux wait again (240 s):
        assert time.monotonic() < d.give_up_at, "the test stalled past the lux deadline"
        assert d.retry_at == d.give_up_at  # capped while its deadline is ahead
    finally:
        svc.shutdown()


def test_write_failure_after_a_lux_wait_backs_off(tmp_path, hw):
    """A bundle waited for the lux sensor (deadline lux_wait_s), then its run cannot write its
    report. Once that deadline has passed, it must still be retried with backoff, not at every
    main-loop pass (a whole calibration run and a failed history row per second). Checked by
    what happens when, not by how long passes take: the run of a pass that began after the
    deadline sets a retry time one backoff after that pass began, status counts down to it,
    passes that end before it run nothing, and a pass after it retries."""
    sim, cfg = hw
    conf = write_config(tmp_path / "g.toml", tmp_path / "state", cfg,
                        light_extra="lux_wait_s = 1.0")
    svc = service(conf, retry_s=0.3, retry_max_s=10.0, reconcile_s=1e9)
    port, regmap = sim.sensor.port, sim.sensor.config
    sim.sensor.stop()
    back = None
    try:
        rdrop(svc.cfg.light.inbox, "b", lux=None)
        svc.tick()
        assert svc.status().daemon.waiting_bundles[0].reason.startswith("waiting for the lux")
        [d] = svc.deferred.values()
        lux_deadline = d.give_up_at
        back = SimLuxSensor(regmap, lux=3000.0, port=port).start()
        with readonly(svc.reports_dir):
            def failed_after_the_deadline() -> float | None:
                """One pass; when it began after the lux deadline and made a run: its start."""
                began, runs = time.monotonic(), svc.history.run_count()
                svc.tick()
                ran = svc.history.run_count() > runs
                return began if ran and began > lux_deadline else None

            began = wait_for(failed_after_the_deadline, 60,
                             "a run in a pass that began after the lux deadline")
            assert svc.history.runs(1)[0].status == "failed"
            d = svc.deferred[d.bundle.hash]
            assert d.delay_s >= 0.6  # 0.3 s (the lux wait), doubled at each failed run
            retry_at = d.retry_at  # (a retry moves d's)
            assert retry_at >= began + d.delay_s  # from that run, not the past deadline
            t0 = time.monotonic()
            [w] = svc.status().to_json()["waiting_bundles"]
            t1 = time.monotonic()
            assert max(retry_at - t1, 0.0) <= w["retry_in_s"] <= retry_at - t0
            runs = svc.history.run_count()
            while True:  # passes that end before the retry time run nothing
                svc.tick()
                if time.monotonic() >= retry_at:
                    break
                assert svc.history.run_count() == runs, "retried before its backoff"
                time.sleep(0.05)
            _passes_until(svc, lambda: svc.history.run_count() > runs,
                          "the retry once its backoff has passed")
    finally:
        if back is not None:
            back.stop()
        svc.shutdown()


def test_last_error_names_a_read_failure_and_clears_after_a_clean_pass(tmp_path, hw):
    """The inbox share goes away: status says the inbox cannot be *read* (not "cannot write
    to"); once it is back, the next clean pass clears ``last_error`` and the error stays
    visible, with its times, under ``last_error_seen``."""
    _, cfg = hw
    share = tmp_path / "share"
    share.mkdir()
    conf = write_config(tmp_path / "g.toml", tmp_path / "state", cfg)
    (tmp_path / "state").mkdir()
    inbox = tmp_path / "state" / "inbox"
    inbox.symlink_to(share)
    svc = service(conf, reconcile_s=1e9)
    try:
        svc.main_loop_pass()
        assert svc.status().to_json()["last_error"] is None
        share.rmdir()  # the share is gone
        svc.main_loop_pass()
        err = svc.status().to_json()["last_error"]
        assert err is not None and f"cannot read {inbox}:" in err, err
        assert "write" not in err and "ENOENT" in err
        assert not share.exists()  # nothing was created in its place
        share.mkdir()  # the share is back
        svc.main_loop_pass()
        st = svc.status().to_json()
        assert st["last_error"] is None
        seen = st["last_error_seen"]
        assert err == f"{seen['at']} {seen['error']}"
        assert seen["cleared_at"] is not None and seen["cleared_at"] >= seen["at"]
    finally:
        svc.shutdown()


def test_status_from_a_socket_thread_while_the_main_loop_defers_bundles(tmp_path, hw):
    """status() runs in a control-socket thread while the main loop adds and drops waiting
    bundles (``_defer`` / ``_process_bundle``) and replaces the config on reload: it must
    read snapshots, never fail with "dictionary changed size during iteration"."""
    _, cfg = hw
    conf = write_config(tmp_path / "g.toml", tmp_path / "state", cfg)
    svc = service(conf)
    old_switch = sys.getswitchinterval()
    try:
        rdrop(svc.cfg.light.inbox, "b1")
        [b] = svc.inbox.poll()
        now = time.monotonic()
        for i in range(300):
            svc.deferred[f"h{i}"] = Deferred(b, "disk full", time.time(), now, 1.0, None)
        stop = threading.Event()

        def main_loop() -> None:  # what the main thread does to the waiting bundles
            i = 300
            while not stop.is_set():
                svc.deferred[f"h{i}"] = Deferred(b, "disk full", time.time(), now, 1.0, None)
                svc.deferred.pop(f"h{i - 300}", None)
                i += 1

        sys.setswitchinterval(1e-6)
        t = threading.Thread(target=main_loop, daemon=True)
        t.start()
        try:
            for _ in range(100):
                st = svc.status().to_json()
                assert 299 <= len(st["waiting_bundles"]) <= 301
        finally:
            stop.set()
            t.join()
    finally:
        sys.setswitchinterval(old_switch)
        svc.shutdown()
