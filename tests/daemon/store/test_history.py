"""State database (SQLite WAL) and atomic writes, against real files and processes."""

from __future__ import annotations

import hashlib
import json
import signal
import sqlite3
import subprocess
import sys
import time

import matplotlib
import pytest
from matplotlib.figure import Figure

from grassd.daemon.core.errors import HistoryError
from grassd.daemon.core.store.atomic import (
    atomic_save_figure,
    atomic_write_bytes,
    atomic_write_json,
)
from grassd.daemon.core.store.history import History

matplotlib.use("Agg")


def test_runs_roundtrip_and_current_table(tmp_path):
    with History(tmp_path / "state.db") as h:
        assert h.journal_mode() == "wal"
        table = list(range(0, 256 * 78, 78))
        r1 = h.start_run("bundle", bundle_hash="abc", input_hashes={"hdri": "11"}, lux=1200.0,
                         lux_source="manifest")
        h.finish_run(r1, "ok", metrics={"r2_after": 0.9995, "max_de": 0.31}, lengths_um=table,
                     table_id=r1, table_crc=0xDEADBEEF, report_path=tmp_path / "r.json")
        r2 = h.start_run("interval")
        h.finish_run(r2, "failed", error="sim exploded")
        h.record_push(r1, "/dev/ttyUSB0#1", True, table_id=r1, table_crc=0xDEADBEEF)
        h.record_push(r1, "/dev/ttyUSB0#2", False, error="timeout")
        cur = h.current_table()
        assert cur is not None and cur.id == r1
        assert cur.lengths_um == tuple(table) and len(cur.lengths_um) == 256
        assert cur.metrics == {"r2_after": 0.9995, "max_de": 0.31}
        assert cur.input_hashes == {"hdri": "11"} and cur.report_path.endswith("r.json")
        assert [r.id for r in h.runs()] == [r2, r1]
        assert h.run(r2).error == "sim exploded" and h.run(r2).status == "failed"
        assert [(p.controller, p.ok) for p in h.pushes(r1)] == [("/dev/ttyUSB0#1", True),
                                                                ("/dev/ttyUSB0#2", False)]
        assert h.ok_run_for_bundle("abc").id == r1 and h.ok_run_for_bundle("zzz") is None
        r3 = h.start_run("request")
        assert h.abandon_running("daemon stopped") == 1
        assert h.run(r3).status == "failed"
    # A second process (a reader such as `grassd status`) sees committed data.
    out = subprocess.run([sys.executable, "-c", f"import sqlite3;print(sqlite3.connect("
                          f"'{tmp_path / 'state.db'}').execute('select count(*) from runs')"
                          f".fetchone()[0])"], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "3"


def test_journal_and_controllers(tmp_path):
    h = History(tmp_path / "s.db")
    e = h.journal_claim("h1", "h1-b", "b")
    assert e.state == "processing" and e.attempts == 0
    assert h.journal_attempt("h1") == 1 and h.journal_attempt("h1") == 2
    h.journal_finish("h1", "rejected", reason="lux -5 <= 0")
    assert h.journal_get("h1").reason == "lux -5 <= 0"
    assert [j.bundle_hash for j in h.journal("rejected")] == ["h1"]
    h.journal_claim("h2", "h2-c", "c")
    h.journal_forget("h2")
    assert h.journal_get("h2") is None
    h.set_controller("a", reachable=True, reported_id=7, reported_crc=99)
    h.set_controller("a", reachable=False, error="gone")
    st = h.controllers()[0]
    assert (st.reported_id, st.reachable, st.last_error) == (7, False, "gone")
    with pytest.raises(ValueError):
        h.journal_finish("h1", "eaten")


def test_not_a_database_is_history_error(tmp_path):
    p = tmp_path / "s.db"
    p.write_bytes(b"this is not sqlite" * 100)
    with pytest.raises(HistoryError, match="cannot open state database"):
        History(p)


def test_atomic_json_and_png(tmp_path):
    p = atomic_write_json(tmp_path / "a" / "r.json", {"x": [1, 2], "p": tmp_path})
    assert json.loads(p.read_text()) == {"x": [1, 2], "p": str(tmp_path)}
    with pytest.raises(ValueError):
        atomic_write_json(p, {"bad": float("nan")})
    assert json.loads(p.read_text())["x"] == [1, 2]  # old content survives a failed write
    assert [f.name for f in p.parent.iterdir()] == ["r.json"]  # no temp file left
    fig = Figure(figsize=(2, 2))
    fig.add_subplot().plot([0, 1], [0, 1])
    png = atomic_save_figure(tmp_path / "plot.png", fig)
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


WRITER = """
import sys, hashlib
from grassd.daemon.core.store.atomic import atomic_write_bytes
i = 0
while True:
    i += 1
    body = (str(i).encode() * 200_000)[:2_000_000]
    atomic_write_bytes(sys.argv[1], hashlib.sha256(body).hexdigest().encode() + b"\\n" + body)
"""


def test_atomic_write_survives_sigkill(tmp_path):
    """Kill a writer mid-stream 8 times: the file is always one complete version."""
    target = tmp_path / "t.bin"
    atomic_write_bytes(target, hashlib.sha256(b"seed").hexdigest().encode() + b"\nseed")
    for k in range(8):
        proc = subprocess.Popen([sys.executable, "-c", WRITER, str(target)])
        time.sleep(0.25 + 0.04 * k)
        proc.send_signal(signal.SIGKILL)
        proc.wait()
        digest, _, body = target.read_bytes().partition(b"\n")
        assert hashlib.sha256(body).hexdigest().encode() == digest


def test_wal_survives_writer_kill(tmp_path):
    """A process killed between commits leaves every committed row readable."""
    code = f"""
from grassd.daemon.core.store.history import History
h = History({str(tmp_path / 's.db')!r})
i = 0
while True:
    i += 1
    r = h.start_run('t'); h.finish_run(r, 'ok', metrics={{'i': i}}, lengths_um=list(range(256)))
"""
    proc = subprocess.Popen([sys.executable, "-c", code])
    time.sleep(1.5)
    proc.kill()
    proc.wait()
    db = sqlite3.connect(tmp_path / "s.db")
    assert db.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
    n = db.execute("select count(*) from runs where status='ok'").fetchone()[0]
    assert n > 0
    h = History(tmp_path / "s.db")
    assert len(h.current_table().lengths_um) == 256
    print(f"committed runs before SIGKILL: {n}")


def test_database_from_before_light_at_gains_the_column(tmp_path):
    """A state database whose runs table lacks light_at (as written before it existed) opens:
    the column is added, old runs read None, new runs store it."""
    from grassd.daemon.core.store import history as hist

    path = tmp_path / "state.db"
    db = sqlite3.connect(path)
    db.executescript(hist._SCHEMA.replace(",\n    light_at      REAL\n", "\n"))
    db.execute("INSERT INTO runs (started_at, trigger, status) VALUES (1.0, 'bundle', 'ok')")
    db.execute("INSERT INTO meta VALUES ('schema', ?)", (str(hist.SCHEMA_VERSION),))
    db.commit()
    assert "light_at" not in {r[1] for r in db.execute("PRAGMA table_info(runs)")}
    db.close()
    with History(path) as h:
        assert h.run(1).light_at is None
        r2 = h.start_run("bundle", light_at=1772352000.0)
        assert h.run(r2).light_at == 1772352000.0
    with History(path) as h:  # opened again: nothing to add
        assert [r.light_at for r in h.runs()] == [1772352000.0, None]


def _old_database(path, schema_version: str) -> None:
    """A state database written before runs.light_at, recording ``schema_version``."""
    from grassd.daemon.core.store import history as hist

    db = sqlite3.connect(path)
    db.execute("PRAGMA journal_mode=WAL")
    db.executescript(hist._SCHEMA.replace(",\n    light_at      REAL\n", "\n"))
    db.execute("INSERT INTO meta VALUES ('schema', ?)", (schema_version,))
    db.commit()
    db.close()


def test_unsupported_schema_is_refused_before_being_altered(tmp_path):
    """A database of another schema version is refused untouched: no light_at column added,
    no table created."""
    path = tmp_path / "state.db"
    _old_database(path, "2")
    db = sqlite3.connect(path)
    db.execute("DROP TABLE run_tables")
    db.commit()
    db.close()
    with pytest.raises(HistoryError, match="schema version 2 is not the supported 1"):
        History(path)
    db = sqlite3.connect(path)
    assert "light_at" not in {r[1] for r in db.execute("PRAGMA table_info(runs)")}
    tables = {r[0] for r in db.execute("SELECT name FROM sqlite_master WHERE type='table'")}
    assert "run_tables" not in tables and "runs" in tables
    db.close()


def test_light_at_added_by_another_process_meanwhile(tmp_path, monkeypatch):
    """Two processes open the same old database at once: the other one adds light_at between
    our look at the columns and our ALTER TABLE (done here from a second connection, run when
    SQLite starts our ALTER). Ours fails with 'duplicate column', which opening tolerates."""
    from grassd.daemon.core.store import history as hist

    path = tmp_path / "state.db"
    _old_database(path, str(hist.SCHEMA_VERSION))
    connect, raced = sqlite3.connect, []

    def racing_connect(*args, **kwargs):
        conn = connect(*args, **kwargs)

        def trace(sql: str) -> None:
            if sql.startswith("ALTER TABLE runs ADD COLUMN light_at") and not raced:
                other = connect(path, isolation_level=None)
                other.execute("ALTER TABLE runs ADD COLUMN light_at REAL")
                other.close()
                raced.append(sql)

        conn.set_trace_callback(trace)
        return conn

    monkeypatch.setattr(hist.sqlite3, "connect", racing_connect)
    with History(path) as h:
        r = h.start_run("bundle", light_at=1772352000.0)
        assert h.run(r).light_at == 1772352000.0
    assert raced  # the other connection did add the column first
