"""`grassd status` and `grassd bundles list` print names an uploader chose: each stays on its
line, with control characters escaped (no terminal escape or forged line reaches the screen)."""

from __future__ import annotations

from status_samples import daemon_state, status, waiting

from grassd.daemon.cli.run import print_status
from grassd.daemon.core.monitoring.status_types import RunSummary
from grassd.daemon.core.store.quarantine import QuarantinedBundle

EVIL = "b1\n<2>forged line\x1b[2J\r"


def test_status_prints_hostile_names_on_one_line_each():
    st = status(
        daemon=daemon_state(waiting_bundles=(waiting(EVIL, "lux " + EVIL, 3.0),),
                            inbox_problems=(f"cannot move bundle {EVIL} out of the inbox",),
                            last_error=f"bundle {EVIL} failed"),
        quarantined=(QuarantinedBundle(bundle=EVIL, name=EVIL, attempts=3, since=0.0,
                                       reason="interrupted"),),
        runs=(RunSummary(id=7, started_at=0.0, finished_at=1.0, trigger="bundle",
                         status="rejected", lux=None, lux_source=None, r2=None,
                         max_dev_de00=None, error=f"bundle {EVIL} rejected", report=None,
                         plot=None),))
    lines: list[str] = []
    print_status(st, echo=lines.append)
    assert all("\n" not in line and "\x1b" not in line and "\r" not in line for line in lines)
    named = [line for line in lines if "b1\\n<2>forged line\\x1b[2J\\r" in line]
    # health (its reasons quote the error and the waiting bundle), last error, waiting,
    # inbox, quarantined, run
    assert len(named) == 6, lines
