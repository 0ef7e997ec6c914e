"""A controller whose table pushes keep failing (simulated controller on a pty whose EEPROM
writes are all torn) is not pushed again at every reconcile pass: its pushes back off (2 s,
doubling) while its status is still read every pass; one warning per attempt; status says when
the next attempt is due. It is pushed at once when it shows that it changed (reports another
table, or answers again after being unreachable for longer than the current delay), after a
reload, and by an explicit push; a status read that fails now and then (noisy bus) does not
end the backoff."""

from __future__ import annotations

import logging
import math
import time

from daemon_harness import after_first_bundle

from grassd.rigs.faults import FaultInjector, FaultPlan


def _fleet_warnings(caplog, name: str) -> list[str]:
    return [r.getMessage() for r in caplog.records
            if r.name == "grassd.daemon.core.hardware.fleet" and r.levelno == logging.WARNING
            and name in r.getMessage()]


def _torn_bus0(sim) -> FaultInjector:
    injector = FaultInjector(FaultPlan(torn_write=1.0))  # every EEPROM write of bus 0 fails
    sim.buses[0].faults = injector
    for dev in sim.buses[0].controllers:
        dev.eeprom.tear_hook = injector.tear
    return injector


def _until_back(svc, bus, bad: str, down_s: float):
    """Unplug ``bus`` for ``down_s`` and reconcile until ``bad`` answers again: its report."""
    bus.unplug(down_s=down_s)
    deadline = time.monotonic() + down_s + 10.0
    seen_down = False
    while time.monotonic() < deadline:
        r = {x.controller: x for x in svc.reconcile()}[bad]
        seen_down |= not r.reachable
        if r.reachable and seen_down:
            return r
        time.sleep(0.05)
    raise AssertionError(f"{bad} did not come back after {down_s} s unplugged")


def test_failing_controller_backs_off_and_is_pushed_on_reset(tmp_path, hw, caplog):
    caplog.set_level(logging.INFO, logger="grassd.daemon.core.hardware.fleet")
    sim, cfg = hw
    svc, _ = after_first_bundle(tmp_path, cfg)
    bad = svc.fleet.controllers[0].name
    injector = _torn_bus0(sim)

    out = svc.scheduled_run("request")  # the run's own push is tried, and fails
    assert out.status == "ok"
    assert [c.ok for c in out.controllers if c.controller == bad] == [False]
    t0 = time.monotonic()
    torn0 = injector.counts.torn_writes
    assert torn0 > 0 and len(_fleet_warnings(caplog, bad)) == 1

    attempts, passes = [], 0
    while time.monotonic() - t0 < 10.0:  # reconcile passes, more often than the daemon's
        r = {x.controller: x for x in svc.reconcile()}[bad]
        passes += 1
        assert not r.ok
        if r.pushed:
            attempts.append(round(time.monotonic() - t0, 2))
        else:
            assert r.retry_in_s is not None and r.retry_in_s > 0  # held back, and says so
        time.sleep(0.1)
    # delays 2, 4, 8 s: attempts near 2 and 6 s; a push every pass would be `passes` of them
    print(f"{passes} reconcile passes in 10 s, push attempts at {attempts} s")
    assert 1 <= len(attempts) <= math.ceil(math.log2(10.0 / 2.0 + 1)) + 1, attempts
    assert passes >= 15  # so that <= 4 attempts means most passes were held back
    assert attempts[0] >= 1.9, attempts
    warnings = _fleet_warnings(caplog, bad)
    assert len(warnings) == 1 + len(attempts)  # the first failure, then one per step
    assert "failures since" in warnings[-1] and "next attempt in" in warnings[-1]
    torn = injector.counts.torn_writes - torn0
    assert torn > 0 and torn <= len(attempts) * torn0  # transfers only at the attempts

    st = {c["name"]: c for c in svc.status().to_json()["controllers"]}
    retry = st[bad]["push_retry"]
    assert retry["failures"] == 1 + len(attempts)
    assert 0 < retry["retry_in_s"] <= retry["delay_s"] == 2.0 * 2 ** len(attempts)
    assert all(c["push_retry"] is None for n, c in st.items() if n != bad)

    # an explicit push (grassd calibrate --now) does not wait for the backoff
    cur = svc.history.current_table()
    [r] = [x for x in svc.fleet.push(cur.lengths_um, cur.table_id) if x.controller == bad]
    assert r.pushed and not r.ok

    # it heals: nothing it reports has changed, so the backoff still holds ...
    injector.enabled = False
    r = {x.controller: x for x in svc.reconcile()}[bad]
    assert not r.pushed and r.retry_in_s > 2.0
    # ... until it shows that it changed: its active bank lost, it answers after a short
    # unplug (power cycle) with another table: then it is pushed at once
    for dev in sim.buses[0].controllers:
        dev.store.invalidate(dev.active_bank)
    r = _until_back(svc, sim.buses[0], bad, down_s=1.0)  # raises unless seen down, then back
    assert r.ok and r.pushed and r.table_id == cur.table_id
    assert svc.status().to_json()["health"] == "ok"
    assert svc.fleet.backoff() == {}
    assert any("active after" in m.getMessage() for m in caplog.records
               if m.name == "grassd.daemon.core.hardware.fleet" and bad in m.getMessage())

    # a new failure streak; a reload ends its backoff: pushed at the next reconcile
    injector.enabled = True
    out = svc.scheduled_run("request")
    r = {x.controller: x for x in svc.reconcile()}[bad]
    assert not r.pushed and r.retry_in_s is not None  # held after the run's failed push
    injector.enabled = False
    assert svc.reload()
    r = {x.controller: x for x in svc.reconcile()}[bad]
    assert r.ok and r.pushed and r.table_id == out.committed.table_id
    svc.shutdown()


def test_backoff_grows_across_status_blips_and_ends_after_a_long_outage(tmp_path, hw):
    """Pushes always fail (torn EEPROM writes). A long outage (3 s unplugged > the 2 s delay)
    counts as a change: the controller is pushed when it answers and its failures start over
    at 1. Short blips (0.2 s, status reads failing now and then) do not: the failures keep
    counting and the delay keeps doubling."""
    sim, cfg = hw
    svc, _ = after_first_bundle(tmp_path, cfg)
    bad = svc.fleet.controllers[0].name
    _torn_bus0(sim)
    svc.scheduled_run("request")  # the run's push fails: failures 1, delay 2 s
    assert svc.fleet.backoff()[bad]["failures"] == 1

    r = _until_back(svc, sim.buses[0], bad, down_s=3.0)
    assert r.pushed and not r.ok  # pushed at once, failed again ...
    b = svc.fleet.backoff()[bad]
    assert (b["failures"], b["delay_s"]) == (1, 2.0)  # ... a new backoff, not its second step

    t0, blips, attempts = time.monotonic(), 0, 0
    while time.monotonic() - t0 < 9.0:
        if time.monotonic() - t0 > blips * 1.5 + 0.5:  # a blip every 1.5 s
            r = _until_back(svc, sim.buses[0], bad, down_s=0.2)
            blips += 1
        else:
            r = {x.controller: x for x in svc.reconcile()}[bad]
        attempts += r.pushed
        time.sleep(0.1)
    b = svc.fleet.backoff()[bad]
    print(f"{blips} blips, {attempts} push attempts in 9 s, backoff {b}")
    assert blips >= 4
    assert attempts <= 3  # due at about 2 and 6 s after the first; every blip would be `blips`
    assert b["failures"] == 1 + attempts >= 2 and b["delay_s"] == 2.0 * 2 ** attempts
    svc.shutdown()


def test_unreachable_controller_is_logged_as_not_answering(tmp_path, hw, caplog):
    """A controller whose status read fails (unplugged: no push tried) is logged as not
    answering, not as a failed push; a push that fails is logged as one."""
    caplog.set_level(logging.INFO, logger="grassd.daemon.core.hardware.fleet")
    sim, cfg = hw
    svc, cur = after_first_bundle(tmp_path, cfg)
    bad = svc.fleet.controllers[0].name
    caplog.clear()
    sim.buses[0].unplug(down_s=1.0)
    r = {x.controller: x for x in svc.reconcile()}[bad]
    assert not r.reachable and not r.pushed
    [w] = _fleet_warnings(caplog, bad)
    assert f"controller {bad}: not answering: " in w and "push failed" not in w, w

    caplog.clear()
    time.sleep(1.2)  # plugged again; now its pushes fail
    _torn_bus0(sim)
    [r] = [x for x in svc.fleet.push(cur.lengths_um, cur.table_id + 1) if x.controller == bad]
    assert r.reachable and r.pushed and not r.ok
    [w] = _fleet_warnings(caplog, bad)
    assert f"controller {bad}: push failed: " in w and "not answering" not in w, w
    svc.shutdown()


def test_refusing_controller_is_logged_as_refusing(tmp_path, hw, caplog):
    """A controller that answers its status request with a NAK (e.g. firmware of another
    protocol version) is reachable: logged once as refusing, with the NAK, never as not
    answering; it is not pushed while it refuses, and is pushed when it answers again."""
    from grassd.firmware_proto.messages import MsgType, Nak, NakCode

    caplog.set_level(logging.INFO, logger="grassd.daemon.core.hardware.fleet")
    sim, cfg = hw
    svc, cur = after_first_bundle(tmp_path, cfg)
    bad = svc.fleet.controllers[0].name
    dev = sim.buses[0].controllers[0]
    dev._status = lambda msg: Nak(MsgType.GET_STATUS, NakCode.UNSUPPORTED_VERSION, 2)
    caplog.clear()
    reports = [{x.controller: x for x in svc.fleet.push(cur.lengths_um, cur.table_id + 1,
                                                        hold=True)}[bad] for _ in range(3)]
    for r in reports:
        assert r.reachable and not r.pushed and not r.ok and "UNSUPPORTED_VERSION" in r.error
    [w] = _fleet_warnings(caplog, bad)
    assert f"controller {bad}: refuses the status request: " in w, w
    assert "not answering" not in w and "push failed" not in w
    del dev._status  # answers again: pushed at once
    [r] = [x for x in svc.fleet.push(cur.lengths_um, cur.table_id + 1, hold=True)
           if x.controller == bad]
    assert r.ok and r.pushed
    svc.shutdown()
