"""Prometheus metrics of the daemon as a file for node_exporter's textfile collector.

The daemon opens no network port: after every run and every reconcile it writes the
exposition (``prometheus_client``'s text format, built by its registry, never by hand)
atomically (temporary file, fsync, rename; the temporary name does not end in ``.prom``, so
the collector never reads half a file) to ``[metrics] textfile``, by default Debian's
``/var/lib/prometheus/node-exporter/grassd.prom`` when that directory exists (package
prometheus-node-exporter), else ``<state_dir>/metrics/grassd.prom``; always the latter with
``--simulate-hardware``.

Metrics (units in the names: seconds, lux, dE00 = CIEDE2000 units):

======================================================  ======================================
``grassd_up``                                           1 while the daemon runs, 0 after a clean
                                                        stop
``grassd_health``                                       0 ok, 1 degraded, 2 failed
                                                        (:mod:`grassd.daemon.core.monitoring.health`)
``grassd_last_success_timestamp_seconds``               end of the last successful run
``grassd_last_success_duration_seconds``                its duration
``grassd_table_id``                                     the active table's id
``grassd_table_ogcd_range_de00``                        OGCD range of the active table
``grassd_table_r2``                                     R^2 of OGCD vs level (closed loop)
``grassd_table_max_deviation_de00``                     largest deviation from the target
``grassd_lux{source}``                                  the latest lux reading of a run and
                                                        where it came from (manifest, modbus)
``grassd_lux_sensor_up``                                1/0: the last read of the Modbus lux
                                                        sensor succeeded (absent: none read)
``grassd_lux_sensor_last_success_timestamp_seconds``    when it last answered
``grassd_bundles{outcome}``                             kept bundles per outcome
                                                        (:mod:`grassd.daemon.core.store.outcomes`)
``grassd_bundle_queue{queue}``                          bundles in inbox/ and processing/
``grassd_controller_reachable{controller}``             1/0
``grassd_controller_in_sync{controller}``               1/0: it reports its desired table
``grassd_controller_push_failures_total{controller}``   failed pushes since the daemon started
``grassd_controller_last_seen_timestamp_seconds``       when it last answered
``grassd_capture_last_success_timestamp_seconds``       the capture station's last capture
                                                        (only with a capture provider)
``grassd_line_recent_unanswered_ratio{port}``           share of the serial line's recent
                                                        request tries without an answer
``grassd_line_chunk_bytes{port}``                       TABLE_CHUNK size its transfer reached
``grassd_line_request_tries_total{port}``               request tries since its bus opened
``grassd_line_request_unanswered_total{port}``          of them without an answer (both
                                                        start again when a reload reopens it)
``grassd_content_source{source}``                       1 for the source the display shows
                                                        (only with [content]; docs/content.md)
``grassd_content_frames_per_second{direction}``         frames out to the controllers and in
                                                        from live senders, per second
``grassd_content_dropped_frames_total``                 live frames replaced before they went
                                                        out
``grassd_content_latency_p99_seconds``                  live packet in to frame out, p99
``grassd_content_bad_packets_total{protocol,reason}``   datagrams dropped: malformed, oversized
======================================================  ======================================

Example alert rules: ``systemd/grassd-alerts.rules.yml``.

A label value (a controller's name, a port) is made one line first by
:func:`~grassd.daemon.core.safe_text.one_line` (a newline or other control character
becomes a visible escape such as ``\\n``, an undecodable byte ``\\xNN``); then
``prometheus_client`` escapes its backslashes and double quotes (``\\\\``, ``\\"``) as the
text format requires, so no value can end its line or its quotes.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from prometheus_client import CollectorRegistry, generate_latest
from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily, Metric
from prometheus_client.registry import Collector

from grassd.daemon.core.monitoring.status_types import ControllerStatus, Status, run_r2
from grassd.daemon.core.monitoring.textfile import (  # the file's path, named here too
    DEBIAN_TEXTFILE_DIR as DEBIAN_TEXTFILE_DIR,
)
from grassd.daemon.core.monitoring.textfile import TEXTFILE_NAME as TEXTFILE_NAME
from grassd.daemon.core.monitoring.textfile import state_dir_textfile as state_dir_textfile
from grassd.daemon.core.monitoring.textfile import textfile_path as textfile_path
from grassd.daemon.core.safe_text import one_line
from grassd.daemon.core.store.atomic import atomic_write_bytes
from grassd.daemon.core.store.history import History, RunRecord
from grassd.daemon.core.store.outcomes import count_outcomes

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class SensorState:
    """The Modbus lux sensor as the daemon last saw it: ``up`` True/False after a read (None:
    not read since start), ``last_success_at`` epoch s of the last good reading."""

    up: bool | None
    last_success_at: float | None


def _label(value: str) -> str:
    """A label value made one line (module docstring); prometheus_client escapes the rest."""
    return one_line(value, None)


class _Snapshot(Collector):
    """One scrape's worth of metrics, built from the values given (see :func:`registry`)."""

    def __init__(self, status: Status, history: History,
                 push_failures: Mapping[str, int], sensor: SensorState | None,
                 capture_at: float | None, up: bool) -> None:
        self.status, self.history = status, history
        self.push_failures, self.sensor, self.capture_at = push_failures, sensor, capture_at
        self.up = up

    def collect(self) -> Iterator[Metric]:
        st, h = self.status, self.history

        def gauge(name: str, doc: str, value: float | None = None,
                  labels: tuple[str, ...] = ()) -> GaugeMetricFamily:
            g = GaugeMetricFamily(name, doc, labels=list(labels) or None)
            if value is not None:
                g.add_metric([], float(value))
            return g

        yield gauge("grassd_up", "1 while the daemon runs, 0 after a clean stop", int(self.up))
        yield gauge("grassd_health", "Health: 0 ok, 1 degraded, 2 failed",
                    st.health.severity)
        cur = h.current_table()
        yield from self._table(cur, gauge)
        lux_run = next((r for r in h.runs(50) if r.lux is not None), None)
        g = gauge("grassd_lux", "Latest ambient illuminance of a run (lux), by source",
                  labels=("source",))
        if lux_run is not None:
            g.add_metric([_label(lux_run.lux_source or "unknown")], lux_run.lux)
        yield g
        if self.sensor is not None:
            if self.sensor.up is not None:
                yield gauge("grassd_lux_sensor_up",
                            "1 when the last read of the Modbus lux sensor succeeded",
                            int(self.sensor.up))
            if self.sensor.last_success_at is not None:
                yield gauge("grassd_lux_sensor_last_success_timestamp_seconds",
                            "When the Modbus lux sensor last gave a reading (epoch s)",
                            self.sensor.last_success_at)
        g = gauge("grassd_bundles", "Bundles kept in the ingest journal, by outcome",
                  labels=("outcome",))
        for outcome, n in count_outcomes(h).items():
            g.add_metric([_label(outcome)], n)
        yield g
        g = gauge("grassd_bundle_queue", "Bundles waiting in inbox/ and processing/",
                  labels=("queue",))
        counts = {} if st.daemon is None else st.daemon.inbox
        for q in ("inbox", "processing"):
            g.add_metric([q], counts.get(q, 0))
        yield g
        yield from self._controllers(st.controllers)
        yield from self._lines({} if st.daemon is None else st.daemon.lines)
        if st.daemon is not None and st.daemon.content is not None:
            yield from self._content(st.daemon.content)
        if self.capture_at is not None:
            yield gauge("grassd_capture_last_success_timestamp_seconds",
                        "When the capture station last delivered a bundle (epoch s)",
                        self.capture_at)

    def _table(self, cur: RunRecord | None, gauge) -> Iterator[Metric]:
        if cur is None or cur.finished_at is None:
            return
        m = cur.metrics
        yield gauge("grassd_last_success_timestamp_seconds",
                    "End of the last successful calibration run (epoch s)", cur.finished_at)
        yield gauge("grassd_last_success_duration_seconds",
                    "Duration of the last successful calibration run (s)",
                    cur.finished_at - cur.started_at)
        yield gauge("grassd_table_id", "Id of the active table", cur.table_id)
        for name, doc, v in (
                ("grassd_table_ogcd_range_de00", "OGCD range of the active table (dE00)",
                 m.get("ogcd_range_de00")),
                ("grassd_table_r2", "R^2 of OGCD vs level of the active table", run_r2(m)),
                ("grassd_table_max_deviation_de00",
                 "Largest OGCD deviation from the target of the active table (dE00)",
                 m.get("max_dev_de00"))):
            if v is not None:
                yield gauge(name, doc, v)

    def _controllers(self, controllers: Sequence[ControllerStatus]) -> Iterator[Metric]:
        lab = ["controller"]
        reach = GaugeMetricFamily("grassd_controller_reachable",
                                  "1 when the controller answered its last status read",
                                  labels=lab)
        sync = GaugeMetricFamily("grassd_controller_in_sync",
                                 "1 when the controller reports its desired table", labels=lab)
        fails = CounterMetricFamily("grassd_controller_push_failures",
                                    "Failed pushes to the controller since the daemon started",
                                    labels=lab)
        seen = GaugeMetricFamily("grassd_controller_last_seen_timestamp_seconds",
                                 "When the controller last answered (epoch s)", labels=lab)
        for c in controllers:
            name = [_label(c.name)]
            reach.add_metric(name, int(c.reachable))
            sync.add_metric(name, int(c.in_sync))
            fails.add_metric(name, self.push_failures.get(c.name, 0))
            if c.last_seen is not None:
                seen.add_metric(name, c.last_seen)
        yield from (reach, sync, fails, seen)

    @staticmethod
    def _content(c: Mapping[str, Any]) -> Iterator[Metric]:
        """What the display shows (the content feature's status, docs/content.md)."""
        src = GaugeMetricFamily("grassd_content_source", "1 for the source the display shows",
                                labels=["source"])
        src.add_metric([_label(c["source"])], 1)
        fps = GaugeMetricFamily("grassd_content_frames_per_second",
                                "Content frames per second: out to the controllers, in from "
                                "live senders", labels=["direction"])
        fps.add_metric(["out"], c["frames_out_per_s"])
        fps.add_metric(["in"], c["frames_in_per_s"])
        dropped = CounterMetricFamily("grassd_content_dropped_frames",
                                      "Live frames replaced by a newer one before they went out")
        dropped.add_metric([], c["dropped"])
        yield from (src, fps, dropped)
        if c.get("latency_ms_p99") is not None:
            lat = GaugeMetricFamily("grassd_content_latency_p99_seconds",
                                    "Live packet in to its frame out, 99th percentile (s)")
            lat.add_metric([], c["latency_ms_p99"] / 1000.0)
            yield lat
        bad = CounterMetricFamily("grassd_content_bad_packets",
                                  "Datagrams the content receivers dropped, by reason",
                                  labels=["protocol", "reason"])
        for proto, counts in (c.get("receivers") or {}).items():
            for reason in ("malformed", "oversized"):
                bad.add_metric([_label(proto), reason], counts.get(reason, 0))
        yield bad

    @staticmethod
    def _lines(lines: Mapping[str, Mapping[str, Any]]) -> Iterator[Metric]:
        """Per serial port the daemon has used (:meth:`Fleet.line_quality`): how requests get
        through. The counters start again when a reload rebuilds the buses."""
        lab = ["port"]
        rate = GaugeMetricFamily("grassd_line_recent_unanswered_ratio",
                                 "Share of the line's recent request tries without an answer",
                                 labels=lab)
        chunk = GaugeMetricFamily("grassd_line_chunk_bytes",
                                  "TABLE_CHUNK size the line's adaptive transfer has reached "
                                  "(bytes)", labels=lab)
        tries = CounterMetricFamily("grassd_line_request_tries",
                                    "Request tries on the line since its bus was opened",
                                    labels=lab)
        fails = CounterMetricFamily("grassd_line_request_unanswered",
                                    "Request tries on the line that got no answer", labels=lab)
        for port, q in lines.items():
            lv = [_label(port)]
            if q.get("recent_failure_rate") is not None:
                rate.add_metric(lv, q["recent_failure_rate"])
            chunk.add_metric(lv, q["chunk_bytes"])
            tries.add_metric(lv, q["tries"])
            fails.add_metric(lv, q["failures"])
        yield from (rate, chunk, tries, fails)


def registry(status: Status, history: History, *,
             push_failures: Mapping[str, int] | None = None, sensor: SensorState | None = None,
             capture_at: float | None = None, up: bool = True) -> CollectorRegistry:
    """A registry holding the metrics of ``status`` (a daemon status, with its health) and
    ``history``; ``push_failures``: failed pushes per controller name since start; ``sensor``:
    the lux sensor's state (None: no sensor configured); ``capture_at``: the capture station's
    last capture (epoch s; None: no capture station); ``up``: False for the last file written
    at a clean stop."""
    reg = CollectorRegistry(auto_describe=False)  # collect once, at generation
    reg.register(_Snapshot(status, history, push_failures or {}, sensor, capture_at, up))
    return reg


def write_textfile(path: str | os.PathLike[str], reg: CollectorRegistry) -> Path:
    """Write ``reg``'s exposition to ``path`` atomically (the directory is created)."""
    return atomic_write_bytes(path, generate_latest(reg))
