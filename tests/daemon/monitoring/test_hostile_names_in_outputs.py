"""Names chosen by whoever writes the inbox (or the configuration's controller names) reach the
status page, the metrics textfile and an alert escaped, never as markup, a second line or a
terminal escape; and the one helper that makes them one line."""

from __future__ import annotations

import json
import sys

from prometheus_client.parser import text_string_to_metric_families
from status_samples import controller, daemon_state, status, waiting

from grassd.daemon.core.config.settings import AlertsConfig
from grassd.daemon.core.monitoring.alerts import Alerter
from grassd.daemon.core.monitoring.health import Health
from grassd.daemon.core.monitoring.metrics import registry, write_textfile
from grassd.daemon.core.monitoring.status_page import render
from grassd.daemon.core.safe_text import MAX_NAME_CHARS, one_line
from grassd.daemon.core.store.history import History

EVIL = "x\n<script>alert(1)</script>\x1b[2J\r\u2028\u202e\udcfe\""


def test_one_line_escapes_what_breaks_a_line_and_cuts_long_names():
    assert one_line("plain name-1.2_ü ☀") == "plain name-1.2_ü ☀"  # printable text stays
    assert one_line(EVIL) == ('x\\n<script>alert(1)</script>\\x1b[2J\\r\\u2028\\u202e\\xfe"')
    assert one_line("a\\nb") == "a\\nb"  # a backslash stays as it is
    assert one_line(b"\x00\x85") == "b'\\x00\\x85'"  # str() of anything else
    long = one_line("\n" * 1000)
    assert long == "\\n" * (MAX_NAME_CHARS // 2) + "...(900 more characters)"
    assert one_line("é" * 1000, None) == "é" * 1000
    for s in (EVIL, "\n" * 300, "\udcff" * 99):  # the result always encodes, on one line
        out = one_line(s)
        out.encode("utf-8")
        assert out.isprintable()


def _history_with(tmp_path, name: str) -> History:
    h = History(tmp_path / "state.db")
    h.journal_claim("h1", f"abc123-{name}", name)
    h.journal_finish("h1", "rejected", reason=f"bundle {name}: manifest.toml\nis not TOML")
    return h


def test_status_page_shows_a_name_escaped_on_one_line(tmp_path):
    h = _history_with(tmp_path, EVIL.replace("\udcfe", "\x85"))  # SQLite takes no surrogate
    st = status(controller(EVIL, reachable=False, in_sync=False, table_id=None,
                           error=f"no answer <b>{EVIL}</b>"),
                daemon=daemon_state(inbox={"inbox": 1}, waiting_bundles=(waiting(EVIL, "r"),)))
    page = render(st, h, timezone="UTC")
    h.close()
    assert "<script" not in page and "<b>" not in page and "\x1b" not in page
    assert "\r" not in page and "\u2028" not in page and "\u202e" not in page
    page.encode("utf-8")  # no lone surrogate
    shown = ('x\\n&lt;script&gt;alert(1)&lt;/script&gt;\\x1b[2J\\r\\u2028\\u202e\\x85'
             "&quot;")
    assert f'"controller">{shown.replace("x85", "xfe")}</td>' in page  # the controller's name
    assert f'"bundle">{shown}</td>' in page  # the bundle's name in a cell of its own
    assert f'"id">abc123-{shown}</td>' in page  # its id
    # a reason keeps its lines (shown pre-wrapped), each escaped
    assert ("bundle x\n&lt;script&gt;alert(1)&lt;/script&gt;\\x1b[2J\\r\\u2028\\u202e"
            "\\x85&quot;: manifest.toml\nis not TOML</td>") in page
    assert f"<li>bundle {shown.replace('x85', 'xfe')} waits: r</li>" in page  # health


def test_metrics_label_values_are_escaped(tmp_path):
    h = History(tmp_path / "state.db")
    name = 'ctl\\"a"\nb\x1b'
    st = status(controller(name, table_id=1, last_seen=5.0), table_id=1,
                daemon=daemon_state(lines={name: {"recent_failure_rate": 0.5,
                                                  "chunk_bytes": 64, "tries": 2,
                                                  "failures": 1}}))
    path = write_textfile(tmp_path / "grassd.prom", registry(st, h))
    h.close()
    text = path.read_text()
    line = next(ln for ln in text.splitlines() if ln.startswith("grassd_controller_in_sync{"))
    assert line == 'grassd_controller_in_sync{controller="ctl\\\\\\"a\\"\\\\nb\\\\x1b"} 1.0'
    labels = {s.labels.get("controller") or s.labels.get("port")
              for fam in text_string_to_metric_families(text) for s in fam.samples
              if s.labels.keys() & {"controller", "port"}}
    assert labels == {'ctl\\"a"\\nb\\x1b'}  # what a scraper reads: one line, no control
    assert all(ln.startswith(("#", "grassd_")) for ln in text.splitlines())


def test_an_alert_describes_names_on_one_line(tmp_path):
    out = tmp_path / "alert.json"
    cmd = f"{sys.executable} -c 'import sys; open(sys.argv[1], \"wb\").write(" \
          f"sys.stdin.buffer.read())' {out}"
    h = History(tmp_path / "state.db")
    a = Alerter(AlertsConfig(command=cmd, min_interval_s=0), h)
    a.observe(Health("ok"))
    st = status(controller(EVIL, in_sync=False, table_id=1, error="a\nb"), controller("ok#1"),
                daemon=daemon_state(waiting_bundles=(waiting(EVIL, "r"),)))
    assert EVIL in st.health.summary()
    assert a.observe(Health("degraded", (f"bundle {EVIL} waits: r",)), st)
    a.wait(30)
    h.close()
    event = json.loads(out.read_text())
    texts = [*event["reasons"], event["health"], event["controllers"][0]["name"],
             event["controllers"][0]["error"], *event["changes"][0]["reasons"]]
    assert all(t.isprintable() for t in texts), texts
    assert event["reasons"] == [f"bundle {one_line(EVIL, None)} waits: r"]
    assert event["controllers"][0]["error"] == "a\\nb"
