"""The daemon's log in a real journald: systemd-journald runs in a namespace of its own
(``systemd-journald NAMESPACE``, sockets in /run/systemd/journal.NAMESPACE, read back with
``journalctl --namespace``), so nothing of the machine's own journal is touched.

- ``grassd run --simulate-hardware`` with standard output and error on a journal stream, as
  systemd connects a service (the stream protocol's header, ``$JOURNAL_STREAM``):
  ``journalctl -p warning`` shows exactly its problems;
- structured fields sent by the native protocol: ``journalctl RUN_ID=12`` finds them.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import socket
import struct
import subprocess
import sys
import time
from pathlib import Path

import pytest
from daemon_harness import CACHE, SITE

JOURNALD = Path("/lib/systemd/systemd-journald")
GRASSD = str(Path(sys.executable).parent / "grassd")
MACHINE_ID = Path("/etc/machine-id")

pytestmark = pytest.mark.skipif(
    not (JOURNALD.exists() and shutil.which("journalctl") and os.geteuid() == 0
         and MACHINE_ID.exists()),
    reason="journald tier needs root, /etc/machine-id and systemd-journald (Debian: apt-get "
           "install systemd)")


@pytest.fixture
def journald():
    """A journald in namespace ``grassdtest<pid>``; yields its name, cleans up after."""
    ns = f"grassdtest{os.getpid()}"
    run_dir = Path(f"/run/systemd/journal.{ns}")
    proc = subprocess.Popen([str(JOURNALD), ns], stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 15
    while not ((run_dir / "socket").is_socket() and (run_dir / "stdout").is_socket()):
        assert proc.poll() is None and time.monotonic() < deadline, "journald did not start"
        time.sleep(0.05)
    yield ns
    proc.send_signal(signal.SIGTERM)
    proc.wait(15)
    mid = MACHINE_ID.read_text().strip()
    for d in (run_dir, Path(f"/run/log/journal/{mid}.{ns}"),
              Path(f"/var/log/journal/{mid}.{ns}")):
        shutil.rmtree(d, ignore_errors=True)


def journal_stream(ns: str, identifier: str) -> socket.socket:
    """A stream into journald as systemd opens one for a service's output: the header
    (identifier, unit, default priority info, read <N> prefixes, no forwarding)."""
    s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    s.connect(f"/run/systemd/journal.{ns}/stdout")
    s.sendall(f"{identifier}\ngrassd.service\n6\n1\n0\n0\n0\n".encode())
    s.shutdown(socket.SHUT_RD)
    return s


def entries(ns: str, *args: str, want: int = 1, timeout: float = 15.0) -> list[dict]:
    """``journalctl --namespace ns -o json ARGS`` (polled until ``want`` entries show)."""
    deadline = time.monotonic() + timeout
    while True:
        r = subprocess.run(["journalctl", f"--namespace={ns}", "--no-pager", "-o", "json",
                            *args], capture_output=True, text=True, check=False)
        out = [json.loads(line) for line in r.stdout.splitlines()]
        if len(out) >= want or time.monotonic() > deadline:
            return out
        time.sleep(0.2)


def text(e: dict) -> str:
    m = e["MESSAGE"]
    return bytes(m).decode() if isinstance(m, list) else m


def test_journalctl_p_warning_shows_exactly_the_daemons_problems(tmp_path, journald):
    from grassd.daemon.core.config.settings import load_default_config
    from grassd.daemon.core.runtime.control import request
    from grassd.rigs.simulated_site import hardware_toml

    state = tmp_path / "state"
    conf = tmp_path / "g.toml"
    conf.write_text(f'state_dir = "{state}"\ncache_dir = "{CACHE}"\n[site]\nlatitude = 35\n'
                    f"longitude = 139\n{hardware_toml(load_default_config())}"
                    "[[viewpoints]]\nh_cm = 170\nd_m = 2\n"
                    '[light]\ninbox = "inbox"\nlux = "manifest"\nsettle_s = 0\n'
                    "[schedule]\ninterval_s = 0\n[simulation]\nsamples = 64\nlengths = 6\n"
                    "[calibration]\ncheck_levels = 5\nmax_rounds = 1\nreplicates = 2\n")
    inbox = state / "inbox"
    inbox.mkdir(parents=True)
    stream = journal_stream(journald, "grassd")
    st = os.fstat(stream.fileno())
    env = {k: v for k, v in os.environ.items() if k not in ("NOTIFY_SOCKET", "RUNTIME_DIRECTORY",
                                                            "STATE_DIRECTORY")}
    env["JOURNAL_STREAM"] = f"{st.st_dev}:{st.st_ino}"
    proc = subprocess.Popen([GRASSD, "run", "--config", str(conf), "--simulate-hardware",
                             "--tick", "0.2"], stdin=subprocess.DEVNULL, stdout=stream,
                            stderr=stream, env=env)
    stream.close()
    try:
        sock = state / "control.sock"
        deadline = time.monotonic() + 120

        def status():
            while True:
                assert proc.poll() is None and time.monotonic() < deadline
                try:
                    return request(sock, {"cmd": "status"}, timeout_s=10)["status"]
                except Exception:  # not up yet
                    time.sleep(0.2)

        status()
        bad = inbox / ".bad"
        bad.mkdir()
        (bad / "sky.exr").write_bytes(b"not an EXR")
        (bad / "manifest.toml").write_text('timestamp = 2026-03-01T12:00:00Z\nhdri = "sky.exr"\n')
        bad.rename(inbox / "bad")
        good = inbox / ".good"
        good.mkdir()
        shutil.copy(SITE, good / "sky.exr")
        (good / "manifest.toml").write_text('timestamp = 2026-03-01T12:00:00Z\n'
                                            'hdri = "sky.exr"\nambient_lux = 3000.0\n')
        good.rename(inbox / "good")
        while status()["health"] != "ok":
            time.sleep(0.2)
    finally:
        proc.send_signal(signal.SIGTERM)
        proc.wait(60)
    everything = entries(journald, "SYSLOG_IDENTIFIER=grassd", want=5)
    print("\n".join(f"{e['PRIORITY']} {text(e)}" for e in everything))
    problems = entries(journald, "-p", "warning", "SYSLOG_IDENTIFIER=grassd")
    assert problems, [text(e) for e in everything]
    lines = [text(e) for e in problems]
    # exactly the problem: the rejected bundle; nothing else (no start-up chatter, no banner)
    assert len(lines) == 1 and "rejected bundle" in lines[0] and "OpenEXR" in lines[0], lines
    info = {text(e): e["PRIORITY"] for e in everything}
    committed = [t for t in info if "run " in t and "committed" in t]
    assert committed and info[committed[0]] == "6"
    assert any("ready" in t for t in info) and any("stopped" in t for t in info)


def native_sender(ns: str):
    """A ``sender_function`` for JournalHandler speaking journald's native protocol to the
    namespace's socket (what sd_journal_send does for the machine's journal): one datagram of
    FIELD=value lines, values with a newline in the binary form (name, LE64 length, data)."""
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    path = f"/run/systemd/journal.{ns}/socket"

    def send(MESSAGE: str, **fields) -> None:  # noqa: N803 - the journal's field name
        parts = []
        for k, v in {"MESSAGE": MESSAGE, **fields}.items():
            data = str(v).encode()
            if b"\n" in data:
                parts.append(k.upper().encode() + b"\n" + struct.pack("<Q", len(data)) + data)
            else:
                parts.append(k.upper().encode() + b"=" + data)
        sock.sendto(b"\n".join(parts) + b"\n", path)

    return send


def test_structured_fields_reach_journald(journald):
    pytest.importorskip("systemd.journal", reason="structured journal fields need "
                        "python3-systemd (apt-get install python3-systemd) or systemd-python")
    import logging

    from grassd.daemon.core.monitoring.journal import SubjectFields, journal_handler

    handler = journal_handler(sender=native_sender(journald))
    handler.addFilter(SubjectFields())
    log = logging.getLogger("grassd.test.journald")
    log.propagate = False
    log.addHandler(handler)
    log.setLevel(logging.INFO)
    try:
        log.info("run %d committed: R^2 %.5f", 12, 0.9993)
        log.warning("controller %s: not answering: %s", "/dev/ttyACM0#2", "timeout")
        log.error("bundle %s failed:\n%s", "3f2a-sky", "Traceback ...\n  boom")
    finally:
        log.removeHandler(handler)
    [run] = entries(journald, "RUN_ID=12")
    assert (text(run), run["PRIORITY"], run["SYSLOG_IDENTIFIER"]) == (
        "run 12 committed: R^2 0.99930", "6", "grassd")
    [ctrl] = entries(journald, "CONTROLLER=/dev/ttyACM0#2")
    assert ctrl["PRIORITY"] == "4" and ctrl["LOGGER"] == "grassd.test.journald"
    [bundle] = entries(journald, "BUNDLE=3f2a-sky", "-p", "err")
    assert text(bundle).endswith("  boom")  # one entry, the traceback inside
