"""Critical sections: the C core's motor loop (fw_tick) run from a timer signal every 20 us, as a
SysTick interrupts the main loop, while the main context sets targets (SET_LEVEL's path) and
reads positions (GET_POSITIONS'); every tick checks each pixel's (target counts, target_um) pair.
With the posix port's fw_irq_save / fw_irq_restore (signals blocked), built under AddressSanitizer
and UBSan, no tick sees a torn pair; without sections (the same program, test/irq_none.c) ticks
do land between the two stores, so the check can see a tear."""

from __future__ import annotations

import re
import subprocess

import pytest
from firmware_tiers import missing_reason

from grassd.rigs.native_build import build_firmware

pytestmark = [pytest.mark.skipif(missing_reason("posix") is not None,
                                 reason=str(missing_reason("posix"))),
              pytest.mark.timeout(120)]


def _run(name: str, seconds: float) -> tuple[int, int, int, str]:
    exe = build_firmware(f"build/{name}", name)
    proc = subprocess.run([str(exe), str(seconds)], capture_output=True, text=True, timeout=60)
    m = re.search(r"irq_torn: (\d+) ticks, (\d+) targets set, (\d+) torn pairs seen",
                  proc.stdout)
    assert m, proc.stdout + proc.stderr
    ticks, sets, torn = (int(x) for x in m.groups())
    assert "runtime error" not in proc.stderr and "AddressSanitizer" not in proc.stderr
    return proc.returncode, ticks, torn, proc.stdout + proc.stderr[-2000:]


def test_with_critical_sections_no_tick_sees_a_torn_target():
    rc, ticks, torn, out = _run("irq_torn", 2.0)
    assert ticks >= 1000, out  # the tick really interrupted the main context, many times
    assert torn == 0 and rc == 0, out


def test_without_them_the_same_check_sees_tears():
    # the control: proves the check above could fail (ticks land between the two stores)
    for _ in range(3):
        rc, ticks, torn, out = _run("irq_torn_unguarded", 1.0)
        if torn:
            break
    assert ticks >= 1000 and torn > 0 and rc == 1, out
