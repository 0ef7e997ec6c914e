"""Log lines for the journal: a real child process whose standard error is the file that
$JOURNAL_STREAM names (as systemd sets it), with and without the systemd.journal module."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

CHILD = """
import json, logging, sys
if sys.argv[1] == "no-module":
    sys.modules["systemd.journal"] = None  # as on a machine without python3-systemd
from grassd.daemon.core.monitoring.journal import setup_logging
native = None
if sys.argv[1] == "native":
    from grassd.daemon.core.monitoring.journal import journal_handler
    out = open(sys.argv[2], "a")
    def sender(MESSAGE, **fields):  # what sd_journal_send gets, written to a file
        fields = {k.upper(): str(v) for k, v in fields.items()}
        out.write(json.dumps({**fields, "MESSAGE": MESSAGE}) + "\\n")
        out.flush()
    native = journal_handler(sender=sender)
setup_logging("debug", native=native)
log = logging.getLogger("grassd.daemon.core.runtime.service")
log.debug("reading the lux sensor")
log.info("run %d committed: R^2 %.5f", 12, 0.99931)
log.warning("controller %s: not answering: %s", "/dev/ttyACM0#2", "timeout")
try:
    raise ValueError("boom")
except ValueError:
    log.exception("run %d failed", 13)  # as the service logs a run's internal error
log.warning("rejected bundle %s: %s", "3f2a-sky", "HDRI is not an OpenEXR file")
log.info("100%% of %s done", "x")
log.warning("explicit", extra={"RUN_ID": 99})
if sys.argv[1] == "no-module":
    raise RuntimeError("bug")  # uncaught: logged at priority 2, traceback lines too
"""


def run_child(tmp_path: Path, mode: str, journal_stream: bool) -> tuple[str, Path]:
    """Run CHILD with standard error in a file (named by $JOURNAL_STREAM when
    ``journal_stream``); returns what it wrote there and the native sender's file."""
    err = tmp_path / f"stderr-{mode}.txt"
    fields = tmp_path / f"fields-{mode}.jsonl"
    env = {k: v for k, v in os.environ.items() if k != "JOURNAL_STREAM"}
    with open(err, "wb") as fh:
        if journal_stream:
            st = os.fstat(fh.fileno())
            env["JOURNAL_STREAM"] = f"{st.st_dev}:{st.st_ino}"
        subprocess.run([sys.executable, "-c", CHILD, mode, str(fields)], stderr=fh,
                       env=env, check=mode == "native", timeout=60)
    return err.read_text(), fields


def test_stderr_lines_carry_syslog_priorities_under_systemd(tmp_path):
    text, _ = run_child(tmp_path, "no-module", journal_stream=True)
    lines = text.splitlines()
    assert lines[5].startswith('<3>  File "<string>", line ')  # the traceback's frame
    lines[5] = "<3>  File ..."
    assert lines[:12] == [
        "<7>grassd.daemon.core.runtime.service: reading the lux sensor",
        "<6>grassd.daemon.core.runtime.service: run 12 committed: R^2 0.99931",
        "<4>grassd.daemon.core.runtime.service: controller /dev/ttyACM0#2: not answering: timeout",
        "<3>grassd.daemon.core.runtime.service: run 13 failed",
        "<3>Traceback (most recent call last):",
        "<3>  File ...",
        "<3>ValueError: boom",
        "<4>grassd.daemon.core.runtime.service: rejected bundle 3f2a-sky: HDRI is not an "
        "OpenEXR file",
        "<6>grassd.daemon.core.runtime.service: 100% of x done",
        "<4>grassd.daemon.core.runtime.service: explicit",
        "<2>grassd: uncaught exception, the program ends",
        "<2>Traceback (most recent call last):",
    ]
    assert lines[-1] == "<2>RuntimeError: bug" and all(ln.startswith("<2>") for ln in lines[10:])
    # journalctl -p warning: priorities 0-4, exactly the problems, tracebacks whole
    problems = [ln for ln in lines if int(ln[1]) <= 4]
    assert len(problems) == len(lines) - 3
    assert not any("committed" in ln or "lux" in ln or "100%" in ln for ln in problems)


def test_terminal_lines_keep_time_and_level(tmp_path):
    text, _ = run_child(tmp_path, "no-module", journal_stream=False)
    first = text.splitlines()[0]
    assert not first.startswith("<")
    assert " DEBUG grassd.daemon.core.runtime.service: reading" in first


def test_journal_stream_of_another_file_is_not_ours(tmp_path):
    other = tmp_path / "other"
    other.write_text("")
    st = os.stat(other)
    from grassd.daemon.core.monitoring.journal import stderr_is_journal

    with open(other) as fh:
        assert stderr_is_journal({"JOURNAL_STREAM": f"{st.st_dev}:{st.st_ino}"}, fh)
    with open(tmp_path / "g.toml", "w") as fh:
        assert not stderr_is_journal({"JOURNAL_STREAM": f"{st.st_dev}:{st.st_ino}"}, fh)
        assert not stderr_is_journal({"JOURNAL_STREAM": "garbage"}, fh)
        assert not stderr_is_journal({}, fh)


def test_native_journal_fields(tmp_path):
    pytest.importorskip("systemd.journal", reason="structured journal fields need "
                        "python3-systemd (apt-get install python3-systemd) or systemd-python")
    text, fields = run_child(tmp_path, "native", journal_stream=True)
    assert text == ""  # everything went to the journal
    entries = [json.loads(line) for line in fields.read_text().splitlines()]
    by_msg = {e["MESSAGE"].split(":")[0]: e for e in entries}
    assert [e["PRIORITY"] for e in entries] == ["7", "6", "4", "3", "4", "6", "4"]
    assert all(e["SYSLOG_IDENTIFIER"] == "grassd" for e in entries)
    assert by_msg["run 12 committed"]["RUN_ID"] == "12"
    assert by_msg["controller /dev/ttyACM0#2"]["CONTROLLER"] == "/dev/ttyACM0#2"
    assert by_msg["run 13 failed"]["RUN_ID"] == "13"
    assert "boom" in by_msg["run 13 failed"]["MESSAGE"]  # one entry with the traceback
    assert by_msg["rejected bundle 3f2a-sky"]["BUNDLE"] == "3f2a-sky"
    assert by_msg["explicit"]["RUN_ID"] == "99"
    assert "RUN_ID" not in by_msg["reading the lux sensor"]
    assert "CONTROLLER" not in by_msg["run 12 committed"]
