"""A running `grassd run` refuses a bundle whose panorama declares more texels than the
renderer holds from the EXR's header: a valid 200 KiB single-part 8192 x 4096 EXR (every
texel 1.0, so nothing but its size is wrong) is rejected with the size and the limit, while
the daemon's peak resident memory stays under 300 MiB (it decoded the map whole before:
1738 MiB, an OOM kill under the unit's MemoryMax=1G), and the daemon goes on to archive the
valid bundle dropped after it."""

from __future__ import annotations

import pytest
from test_grassd_run_end_to_end import Daemon, manifest, wait_for

from grassd.rigs.inbox_fuzz import ATTACKS, drop_attack
from grassd.rigs.peak_memory import proc_mib

pytestmark = pytest.mark.timeout(300)

WAIT_S = 90.0
PEAK_MIB = 300.0


def _reason(d: Daemon, name: str) -> str:
    def found():
        for p in (d.state / "rejected").iterdir():
            if p.name.split("-", 1)[-1] == name and (p / "reason.txt").is_file():
                return (p / "reason.txt").read_text()
        return None
    return wait_for(found, WAIT_S, f"bundle {name} rejected with a reason", d)


def test_8192_x_4096_exr_refused_from_its_header_in_little_memory(tmp_path):
    d = Daemon(tmp_path)
    d.start()
    try:
        pid = d.proc.pid
        idle = proc_mib(pid)
        with open(f"/proc/{pid}/clear_refs", "w") as fh:  # VmHWM from now on
            fh.write("5")
        build, word = ATTACKS["exr-8192x4096"]
        drop_attack(d.state / "inbox", "exr-8192x4096", build, manifest(100, lux=1000.0))
        reason = _reason(d, "exr-8192x4096")
        peak = proc_mib(pid, "VmHWM")
        print(f"\n  {reason.strip()}\n  daemon RSS idle {idle:.0f} MiB, peak {peak:.0f} MiB")
        assert word in reason
        assert "sky.exr: 8192 x 4096 = 33554432 texels" in reason
        assert "nothing was decoded" in reason
        assert peak < PEAK_MIB, (idle, peak)
        d.drop("valid", manifest(101, lux=3000.0))
        wait_for(lambda: any(p.name.endswith("-valid") for p in (d.state / "archive").iterdir()),
                 WAIT_S, "the valid bundle archived after the refused one", d)
    finally:
        d.close()
