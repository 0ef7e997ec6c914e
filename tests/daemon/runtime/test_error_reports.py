"""How the daemon reports errors: status's last_error stays while a bundle still waits on it and
does not flip between passes of a failing reconcile; a controllers command refused by a running
daemon's state lock names that daemon, not a dead one."""

from __future__ import annotations

import time

from daemon_harness import drop, full, service, tmpfs, write_config


def test_last_error_stays_while_a_bundle_still_waits_on_it(tmp_path, hw):
    """A bundle deferred by a full state disk retries with backoff (seconds to minutes): the
    passes in between do not retry it, so they must not report the error as cleared (status
    would show no error, and the log "has cleared", while the disk is still full). It clears
    once the bundle went through."""
    _, cfg = hw
    with tmpfs(tmp_path / "state") as state:
        conf = write_config(tmp_path / "g.toml", state, cfg)
        svc = service(conf, retry_s=60.0, reconcile_s=1e9)
        try:
            drop(svc.cfg.light.inbox, "b1", lux=1000.0)
            claimed = svc.inbox.poll()
            assert len(claimed) == 1
            with full(state):
                svc.tick(claimed)
                assert "full" in (svc.status().to_json()["last_error"] or "")
                svc.main_loop_pass()  # the bundle's retry is not due: nothing was retried
                st = svc.status().to_json()
                assert [w["bundle"] for w in st["waiting_bundles"]] == ["b1"]
                assert "full" in (st["last_error"] or ""), st["last_error"]
            for d in svc.deferred.values():  # space is back: retry now
                d.retry_at = time.monotonic()
            svc.main_loop_pass()
            st = svc.status().to_json()
            assert st["waiting_bundles"] == [] and svc.inbox.counts()["archive"] == 1
            svc.main_loop_pass()
            st = svc.status().to_json()
            assert st["last_error"] is None
            assert st["last_error_seen"]["cleared_at"] is not None
        finally:
            svc.shutdown()


def test_daemon_refused_by_a_controllers_command_does_not_name_a_dead_daemon(tmp_path):
    """A daemon killed with SIGKILL leaves its PID in grassd.lock (only a clean release
    empties it). A `grassd controllers` command holding the shared lock must not make the
    next daemon's refusal name that dead process as the holder."""
    import subprocess
    import sys

    import pytest

    from grassd.daemon.core.errors import StateDirLocked
    from grassd.daemon.core.runtime.statelock import StateLock

    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()  # a PID that no longer runs
    state = tmp_path / "state"
    state.mkdir()
    (state / "grassd.lock").write_text(f"{dead.pid} grassd run\n")  # what it left
    with StateLock(state).shared(lambda who: f"held by {who}"):
        with pytest.raises(StateDirLocked) as exc:
            StateLock(state, "grassd run").acquire()
    msg = str(exc.value)
    assert f"PID {dead.pid}" not in msg, msg
    assert "grassd controllers" in msg, msg


def test_last_error_of_a_failing_reconcile_does_not_flip_between_passes(tmp_path, hw):
    """A reconcile that fails at every attempt (full state disk: recording an unplugged
    controller's state fails) ends every pass that reconciles, i.e. every ``reconcile_s``;
    the passes in between do not reconcile and must not report it as cleared (before, status
    showed the error in one pass out of three and the log said "cleared" as often)."""
    sim, cfg = hw
    with tmpfs(tmp_path / "state") as state:
        conf = write_config(tmp_path / "g.toml", state, cfg)
        svc = service(conf, reconcile_s=1.0)
        try:
            drop(svc.cfg.light.inbox, "b1", lux=1000.0)
            svc.main_loop_pass()
            assert svc.history.current_table() is not None and svc.last_error is None
            seen = []
            with full(state):
                sim.buses[0].unplug(down_s=60.0)
                t0 = time.monotonic()
                while time.monotonic() - t0 < 5.0:
                    svc.main_loop_pass()
                    seen.append(svc.status().to_json()["last_error"])
                    time.sleep(0.3)
            first = next(i for i, e in enumerate(seen) if e is not None)
            assert first <= 6 and "full" in seen[first], seen
            assert all(e is not None for e in seen[first:]), seen
            deadline = time.monotonic() + 10.0  # space is back: the next reconcile clears it
            while svc.status().to_json()["last_error"] is not None:
                assert time.monotonic() < deadline
                svc.main_loop_pass()
                time.sleep(0.3)
            assert svc.status().to_json()["last_error_seen"]["cleared_at"] is not None
        finally:
            svc.shutdown()
