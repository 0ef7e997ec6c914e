"""`grassd status` and `grassd bundles list` print names an uploader chose: each stays on its
line, with control characters escaped (no terminal escape or forged line reaches the screen)."""

from __future__ import annotations

from grassd.daemon.cli.run import print_status

EVIL = "b1\n<2>forged line\x1b[2J\r"


def test_status_prints_hostile_names_on_one_line_each():
    st = {"running": True, "pid": 1, "health": "ok", "controllers": [],
          "waiting_bundles": [{"bundle": EVIL, "retry_in_s": 3.0, "reason": "lux " + EVIL}],
          "inbox_problems": [f"cannot move bundle {EVIL} out of the inbox"],
          "quarantined": [{"bundle": EVIL, "attempts": 3, "since": 0.0}],
          "last_error": f"bundle {EVIL} failed",
          "runs": [{"id": 7, "started_at": 0.0, "trigger": "bundle", "status": "rejected",
                    "r2": None, "error": f"bundle {EVIL} rejected"}]}
    lines: list[str] = []
    print_status(st, echo=lines.append)
    assert all("\n" not in line and "\x1b" not in line and "\r" not in line for line in lines)
    named = [line for line in lines if "b1\\n<2>forged line\\x1b[2J\\r" in line]
    assert len(named) == 5, lines  # last error, waiting, inbox, quarantined, run
