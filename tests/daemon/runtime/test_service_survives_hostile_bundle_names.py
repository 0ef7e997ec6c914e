"""A bundle's name is chosen by whoever writes the inbox: a real `grassd run`
under a stand-in for systemd ($NOTIFY_SOCKET a datagram socket this test reads, standard error
the journal stream named by $JOURNAL_STREAM) gets a valid bundle whose name holds a newline,
a forged priority prefix, sd_notify assignments, an ANSI escape and markup. It keeps running and
applies the bundle; every STATUS= stays one assignment; every record in its journal output is
one line; the status page shows a rejected bundle's hostile name escaped.

Before: sd_notify raised on the newline in STATUS= and the daemon died (three times, then
quarantine), and the journal format printed a forged second line with the record's priority.
Every wait is bounded (the harness's wait_for), so a daemon that dies or hangs fails the test.
"""

from __future__ import annotations

import os
import re

import pytest
from test_grassd_run_end_to_end import Daemon, manifest, wait_for

from grassd.daemon.core.store.layout import PAGE_NAME

#: a calibration or a rejection on a loaded CI machine
WAIT_S = 120.0
#: newline, a line that journald would file at priority 2, sd_notify assignments, a terminal
#: escape, markup
EVIL = "sky\n<2>grassd: FORGED critical\nREADY=1\nMAINPID=1\x1b[31m<img src=x onerror=alert(1)>"
ESCAPED = r"sky\n<2>grassd: FORGED critical\nREADY=1\nMAINPID=1\x1b[31m<img src=x onerror=alert(1)>"


class JournalDaemon(Daemon):
    """The harness's daemon with its standard error as the journal stream ($JOURNAL_STREAM
    names the log file), so it writes the ``<N>``-prefixed journal format."""

    def start(self) -> None:
        self.log.touch()
        st = os.stat(self.log)
        os.environ["JOURNAL_STREAM"] = f"{st.st_dev}:{st.st_ino}"
        try:
            super().start()
        finally:
            del os.environ["JOURNAL_STREAM"]


@pytest.fixture(scope="module")
def daemon(tmp_path_factory):
    d = JournalDaemon(tmp_path_factory.mktemp("names"))
    d.start()
    yield d
    d.close()


def _archived(d: Daemon, part: str) -> bool:
    return any(part in p.name for p in (d.state / "archive").iterdir())


def test_a_valid_bundle_with_a_newline_in_its_name_is_applied(daemon):
    d = daemon
    d.drop(EVIL, manifest(1, lux=3000.0))
    wait_for(lambda: _archived(d, "sky"), WAIT_S, "the hostile-named bundle archived", d)
    wait_for(lambda: d.status()["run_counts"]["ok"] == 1, WAIT_S, "its run ok", d)
    d.drop("after", manifest(2, lux=3000.0))  # and the daemon goes on
    wait_for(lambda: _archived(d, "after"), WAIT_S, "the next bundle archived", d)
    assert d.proc is not None and d.proc.poll() is None
    d.drain()
    datagrams = list(d.messages)
    # every line of every datagram is one assignment; no name forged one
    keys = {"READY", "STATUS", "MAINPID", "WATCHDOG", "RELOADING", "STOPPING",
            "MONOTONIC_USEC"}
    for msg in datagrams:
        for ln in msg.split("\n"):
            key, eq, value = ln.partition("=")
            assert eq and key in keys and "\n" not in value, msg
            assert key == "STATUS" or "FORGED" not in value, msg  # only inside a STATUS value
            assert key != "MAINPID" or value == str(d.proc.pid), msg
    assert f"STATUS=processing bundle {ESCAPED}" in datagrams
    assert sum(m.startswith("READY=1") for m in datagrams) == 1  # at start only


def test_status_page_shows_the_name_escaped(daemon):
    d = daemon
    bad = "bad\n<script>alert(2)<script>"
    d.drop(bad, manifest(3, lux=3000.0), files={"sky.exr": b"not an EXR"})
    wait_for(lambda: any(p.name.startswith(".") is False and "bad" in p.name
                         for p in (d.state / "rejected").iterdir()), WAIT_S,
             "the hostile-named bad bundle rejected", d)
    d.drop("good", manifest(4, lux=3000.0))  # a run rewrites the page
    wait_for(lambda: _archived(d, "good"), WAIT_S, "the next bundle archived", d)
    page = d.state / "reports" / PAGE_NAME
    wait_for(lambda: page.is_file() and "alert(2)" in page.read_text(), WAIT_S,
             "the page listing the rejected bundle", d)
    text = page.read_text()
    assert "<script" not in text
    assert r">bad\n&lt;script&gt;alert(2)&lt;script&gt;</td>" in text


def test_journal_output_is_one_line_per_record(daemon):
    """A bundle whose light is older than the active table's is archived unused, and the
    pipeline logs its name: one line, escaped, under the record's priority."""
    d = daemon
    wait_for(lambda: _archived(d, "good"), WAIT_S, "the previous tests' bundles", d)
    d.drop(f"old {EVIL}", manifest(0, lux=3000.0))
    wait_for(lambda: "archived unused" in d.log.read_text(errors="replace"), WAIT_S,
             "the old bundle archived unused", d)
    lines = d.log.read_text(errors="replace").splitlines()
    prefixed = [ln for ln in lines if re.match(r"<[0-7]>", ln)]
    # the only other lines: Taichi's banner on standard output (the same file here)
    assert all(ln.startswith("[Taichi]") for ln in lines if ln not in prefixed), lines
    assert not any("\x1b" in ln for ln in lines)
    [line] = [ln for ln in lines if "archived unused" in ln]
    assert line.startswith(f"<4>grassd.daemon.core.runtime.bundle_pipeline: bundle old {ESCAPED} "
                           "archived unused: superseded: its light")
    assert not any(ln.startswith(("<2>grassd: FORGED", "READY=1", "MAINPID", "<img"))
                   for ln in lines)
