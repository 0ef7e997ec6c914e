"""A serial line's quality in words, for ``grassd status`` and the status page: an operator
sees a cable going bad (requests retried, TABLE_CHUNKs cut short) before pushes start to fail.
The metrics carry the same numbers (:mod:`grassd.daemon.core.monitoring.metrics`).

The numbers come from :meth:`grassd.daemon.core.hardware.fleet.Fleet.line_quality` (one
:meth:`~grassd.firmware_proto.line_quality.LineQuality.snapshot` per port) and are also in
``grassd status --json`` under ``lines``.
"""

from __future__ import annotations

from collections.abc import Mapping

from grassd.firmware_proto.line_quality import NOISY_RATE

#: Share of recent request tries without an answer from which a line is called failing (from
#: NOISY_RATE on it is noisy): most frames are damaged.
FAILING_RATE = 0.5


def line_verdict(q: Mapping[str, object]) -> str:
    """"unused", "good", "noisy" or "failing" for snapshot ``q`` of one line."""
    rate = q.get("recent_failure_rate")
    if rate is None:
        return "unused"
    if rate >= FAILING_RATE:
        return "failing"
    shrunk = q["chunk_bytes"] < q["max_chunk_bytes"]
    return "noisy" if rate >= NOISY_RATE or shrunk else "good"


def describe_line(port: str, q: Mapping[str, object]) -> str:
    """One line for ``grassd status``: the verdict, the share of recent request tries that got
    no answer (%), the TABLE_CHUNK size reached against its limit (bytes), and what to do."""
    verdict = line_verdict(q)
    if verdict == "unused":
        return f"{port}: no requests yet"
    text = (f"{port}: {verdict}, {q['recent_failure_rate']:.1%} of the last "
            f"{q['recent_tries']} request tries unanswered, chunk {q['chunk_bytes']} of "
            f"{q['max_chunk_bytes']} bytes")
    if q.get("last_push_tries") is not None:
        text += f", last push {q['last_push_tries']} tries at {q['last_push_chunk_bytes']} B"
    if verdict == "noisy":
        text += "; check the cable, its shield and termination before pushes fail"
    elif verdict == "failing":
        text += ("; most frames are damaged: check the cable, termination, ground and baud "
                 "rate")
    return text
