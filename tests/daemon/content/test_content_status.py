"""What the operator sees of content: a playing player's status through the daemon's status
JSON, ``grassd status``'s line, the Prometheus metrics and the status page."""

from __future__ import annotations

import json
import time

import numpy as np
from content_helpers import content_config
from prometheus_client import generate_latest
from status_samples import daemon_state, status

from grassd.daemon.cli.run import print_status
from grassd.daemon.content.card import content_card
from grassd.daemon.content.feature import ContentFeature
from grassd.daemon.content.player import ContentPlayer
from grassd.daemon.core.monitoring.metrics import registry
from grassd.daemon.core.monitoring.page_parts import Clock
from grassd.daemon.core.monitoring.status_page import render
from grassd.daemon.core.monitoring.status_types import Status
from grassd.daemon.core.store.history import History


def test_status_line_and_metrics_of_a_playing_source(ports, sink, sacn_senders, tmp_path,
                                                      capsys):
    p = ContentPlayer(content_config(ports, artnet_enabled=False, hold_s=5.0), 4, 8,
                      sink).start()
    try:
        snd = sacn_senders(ports[0])
        for k in range(20):
            snd[1].dmx_data = (k,) * 32
            time.sleep(1 / 30)
        sink.wait_for(lambda f: np.all(f == 19))
        time.sleep(0.6)
        content = p.status().to_json()
    finally:
        p.stop()
    st = status(daemon=daemon_state(content=content))
    back = Status.from_json(json.loads(json.dumps(st.to_json())))
    assert back.daemon.content == content
    print_status(back)
    line = next(s for s in capsys.readouterr().out.splitlines() if s.startswith("content:"))
    assert line.startswith("content: sacn (1 sender(s)), ") and "frames/s out" in line
    assert "latency" in line and "map nearest_de00" not in line  # no calibration: luminance
    with History(tmp_path / "h.sqlite") as h:
        text = generate_latest(registry(back, h)).decode()
    assert 'grassd_content_source{source="sacn"} 1.0' in text
    out = next(float(s.split()[-1]) for s in text.splitlines()
               if s.startswith('grassd_content_frames_per_second{direction="out"}'))
    assert 20 <= out <= 40, out
    assert 'grassd_content_bad_packets_total{protocol="sacn",reason="malformed"} 0.0' in text
    assert "grassd_content_latency_p99_seconds" in text
    with History(tmp_path / "h.sqlite") as h:
        page = render(back, h, timezone="UTC",
                      cards=[content_card(back.daemon.content, None, Clock("UTC"))])
    assert "<h2>Content</h2>" in page and '<td data-label="source">sacn</td>' in page
    assert page.index("<h2>Serial lines</h2>") < page.index("<h2>Content</h2>") \
        < page.index("<h2>Last runs</h2>")
    assert ContentFeature().card(None, Clock("UTC")) is None  # no content plays: no card


def test_a_status_without_content_has_no_content_metrics(tmp_path):
    st = status(daemon=daemon_state())
    js = st.to_json()
    assert js["content"] is None
    del js["content"]  # a daemon from before content
    assert Status.from_json(js).daemon.content is None
    with History(tmp_path / "h.sqlite") as h:
        assert "grassd_content" not in generate_latest(registry(st, h)).decode()
