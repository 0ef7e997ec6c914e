"""One log record is one line, whatever a name in it holds, and logging never stops the
program: real child processes whose standard error is the journal stream
($JOURNAL_STREAM) or a terminal, logging names chosen by whoever writes the inbox."""

from __future__ import annotations

import logging
import os
import re
import subprocess
import sys
from pathlib import Path

from grassd.daemon.core.monitoring.journal import OneLineFormatter, SubjectFields

#: a name that, written raw, would forge a critical record, recolour a terminal and reorder text
EVIL = "b1\n<2>grassd: forged critical\r\x1b[31m\u202egnp.exe\udcff"

CHILD = """
import logging, sys
sys.modules["systemd.journal"] = None  # stderr format even where python3-systemd exists
from grassd.daemon.core.monitoring.journal import setup_logging
EVIL = %r
setup_logging("debug")
log = logging.getLogger("grassd.daemon.core.store.ingest")
log.warning("bundle %%s rejected: %%s", EVIL, "manifest.toml: bad\\nvalue")
log.info("bundle " + EVIL + " formatted before logging")
try:
    raise ValueError("cannot read " + EVIL)
except ValueError:
    log.exception("bundle %%s failed", EVIL)
log.info("last")
"""


def run_child(tmp_path: Path, journal_stream: bool, code: str = CHILD) -> str:
    err = tmp_path / "stderr.txt"
    env = {k: v for k, v in os.environ.items() if k != "JOURNAL_STREAM"}
    with open(err, "wb") as fh:
        if journal_stream:
            st = os.fstat(fh.fileno())
            env["JOURNAL_STREAM"] = f"{st.st_dev}:{st.st_ino}"
        subprocess.run([sys.executable, "-c", code % EVIL if "%r" in code else code],
                       stderr=fh, env=env, check=True, timeout=60)
    return err.read_bytes().decode("utf-8", "replace")


def test_journal_stream_lines_one_record_each(tmp_path):
    lines = run_child(tmp_path, journal_stream=True).split("\n")
    assert lines[-1] == ""  # ends with a newline
    lines = lines[:-1]
    assert all(re.match(r"<[0-7]>", ln) for ln in lines), lines
    assert not any("\x1b" in ln or "\r" in ln or "\u202e" in ln for ln in lines)
    name = r"b1\n<2>grassd: forged critical\r\x1b[31m\u202egnp.exe\xff"
    assert lines[0] == (f"<4>grassd.daemon.core.store.ingest: bundle {name} rejected: "
                        r"manifest.toml: bad\nvalue")
    assert lines[1] == f"<6>grassd.daemon.core.store.ingest: bundle {name} formatted before logging"
    assert lines[2] == f"<3>grassd.daemon.core.store.ingest: bundle {name} failed"
    # the traceback keeps its lines, under the record's priority; the exception's text in it
    # is one line
    assert lines[3] == "<3>Traceback (most recent call last):"
    assert lines[-2] == f"<3>ValueError: cannot read {name}"
    assert all(ln.startswith("<3>") for ln in lines[3:-1])
    assert lines[-1] == "<6>grassd.daemon.core.store.ingest: last"
    assert not any(ln.startswith("<2>") for ln in lines)


def test_terminal_lines_one_record_each(tmp_path):
    lines = run_child(tmp_path, journal_stream=False).splitlines()
    assert "\x1b" not in "".join(lines) and "\r" not in "".join(lines)
    assert " WARNING grassd.daemon.core.store.ingest: bundle b1\\n<2>grassd: forged" in lines[0]
    assert [ln for ln in lines if "forged critical" in ln and "Error" not in ln] == lines[:3]
    assert lines[-1].endswith(" INFO grassd.daemon.core.store.ingest: last")


FAILING = """
import logging, sys
from grassd.daemon.core.monitoring.journal import setup_logging

class Broken:  # a stream whose every write fails, as a gone journal stream does
    def write(self, text):
        raise BrokenPipeError(32, "Broken pipe")
    def flush(self):
        raise BrokenPipeError(32, "Broken pipe")

class Deep:
    def __str__(self):
        raise RecursionError("maximum recursion depth exceeded")

setup_logging("info", stream=Broken())
log = logging.getLogger("grassd")
for i in range(100):
    log.warning("bundle %s: %d", "x", i)
log.warning("bundle %s", Deep())  # logging's StreamHandler passes RecursionError on
log.warning("bad format %d", "not a number")
print("still running")
"""


def test_a_failing_handler_never_stops_the_program(tmp_path):
    """Every write fails (and a message cannot even be formatted): the program goes on; each
    kind of failure is reported once, in one line, on the real standard error."""
    r = subprocess.run([sys.executable, "-c", FAILING], capture_output=True, text=True,
                       timeout=60, check=False)
    assert r.returncode == 0 and r.stdout == "still running\n", r.stderr
    reports = r.stderr.splitlines()
    assert len(reports) == 3, reports
    assert all(ln.startswith("<4>grassd: logging through StreamHandler failed: ")
               for ln in reports)
    assert [ln.split("failed: ")[1].split(":")[0] for ln in reports] == [
        "BrokenPipeError", "RecursionError", "TypeError"]


def test_structured_fields_are_one_line():
    """``BUNDLE`` (journalctl BUNDLE=...) holds the name made one line; a record whose
    arguments cannot be read passes without fields instead of raising."""
    rec = logging.LogRecord("grassd", logging.WARNING, __file__, 1, "bundle %s rejected: %s",
                            (EVIL, "x"), None)
    assert SubjectFields().filter(rec)
    assert rec.BUNDLE == r"b1\n<2>grassd: forged critical\r\x1b[31m\u202egnp.exe\xff"
    odd = logging.LogRecord("grassd", logging.INFO, __file__, 1, "bundle %s", None, None)
    odd.args = object()  # type: ignore[assignment]
    assert SubjectFields().filter(odd) and not hasattr(odd, "BUNDLE")
    text = OneLineFormatter("%(message)s").format(rec)
    assert "\n" not in text and text.startswith(r"bundle b1\n<2>grassd")
    assert rec.getMessage().count("\n") == 1  # the record itself is left as it was
