"""Test patterns (:mod:`grassd.daemon.measure.patterns`) on the Python model's controllers on a
real pty: a controller that reboots while its motors are within tolerance of the pattern keeps
its photo and is sent the pattern again; one whose pixels then move away has its photo refused;
one that reboots on the way to a pattern is sent it again and the pattern is shown."""

from __future__ import annotations

import re
import threading
import time
from contextlib import ExitStack

import numpy as np
import pytest

from grassd.daemon.core.config.settings import ControllerConfig
from grassd.daemon.core.hardware.fleet import Fleet
from grassd.daemon.measure.patterns import PatternError, PatternSession
from grassd.rigs.firmware import Controller, simulated_config
from grassd.rigs.simulator import SimulatedBus

PIX = 8
#: slow motors (um/s) and a wide tolerance (um): a pattern is taken as shown about 2 s before
#: the motors arrive, so a reboot then stops them short of it, but within tolerance
SPEED, TOLERANCE = 2_000.0, 5_000
LONG_MM = 18.0


@pytest.fixture
def line(tmp_path):
    """(the two model controllers, their configs, a fleet on the line) with a table pushed."""
    with ExitStack() as stack:
        ctrls = [Controller(simulated_config(a, n_pixels=PIX, speed_um_s=SPEED),
                            tmp_path / f"c{a}.eeprom") for a in (1, 2)]
        bus = stack.enter_context(SimulatedBus(ctrls))
        cfgs = [ControllerConfig(port=bus.path, address=a, pixels=((k * PIX, k * PIX + PIX - 1),))
                for k, a in enumerate((1, 2))]
        fleet = stack.enter_context(Fleet(cfgs))
        table = np.linspace(0, 1000, 256).astype(np.uint16)  # level 0..255 -> 0..1 mm
        assert all(r.ok for r in fleet.push({c.name: table for c in cfgs}, 7))
        yield ctrls, cfgs, fleet


def _session(fleet, cfgs, settle_s: float = 30.0) -> PatternSession:
    return PatternSession(fleet, cfgs, 2 * PIX, timeout_s=60.0, settle_s=settle_s,
                          tolerance_um=TOLERANCE)


def test_a_reboot_holding_the_pattern_keeps_the_photo(line):
    ctrls, cfgs, fleet = line
    victim = ctrls[0]
    with _session(fleet, cfgs) as session:
        session.show(LONG_MM)
        victim.power_cycle()  # the motors stop where they are: short of the pattern, near it
        stopped = victim.targets_um()
        assert not victim.in_pattern and np.all(stopped < LONG_MM * 1000)
        assert np.all(np.abs(stopped - LONG_MM * 1000) <= TOLERANCE)
        session.wait_shown()  # the photo stands ...
        assert victim.in_pattern  # ... and the pattern is shown again
        np.testing.assert_array_equal(victim.targets_um(), np.full(PIX, LONG_MM * 1000))


def test_pixels_that_moved_away_during_the_photo_refuse_it(line):
    ctrls, cfgs, fleet = line
    victim = ctrls[0]
    with _session(fleet, cfgs) as session:
        session.show(LONG_MM)
        victim.power_cycle()
        fleet.client(cfgs[0]).set_levels(cfgs[0].address, np.zeros(PIX, np.uint8))  # content: 0 mm
        deadline = time.monotonic() + 10
        while np.all(np.abs(victim.positions_um() - LONG_MM * 1000) <= TOLERANCE):
            assert time.monotonic() < deadline, "the victim's motors never moved"
            time.sleep(0.05)
        left = re.escape(f"{cfgs[0].name} left the test pattern during the photo")
        with pytest.raises(PatternError, match=left):
            session.wait_shown()


def test_a_reboot_on_the_way_to_a_pattern_is_sent_it_again(line):
    ctrls, cfgs, fleet = line
    victim = ctrls[1]
    cut = threading.Timer(1.0, victim.power_cycle)  # 2 mm into a 9 s travel
    with _session(fleet, cfgs) as session:
        cut.start()
        try:
            session.show(LONG_MM)
        finally:
            cut.join()
        assert victim.boots == 2
        for c in ctrls:
            assert c.in_pattern
            np.testing.assert_array_equal(c.targets_um(), np.full(PIX, LONG_MM * 1000))
            assert np.all(np.abs(c.positions_um() - LONG_MM * 1000) <= TOLERANCE)
