"""Where the daemon's metrics file goes (:mod:`grassd.daemon.core.monitoring.metrics` writes it).

Its own module, without ``prometheus_client``: ``grassd check-config`` prints the path and
starts without the exposition code.
"""

from __future__ import annotations

from pathlib import Path

#: Debian's directory for node_exporter's textfile collector (package prometheus-node-exporter)
DEBIAN_TEXTFILE_DIR = Path("/var/lib/prometheus/node-exporter")
TEXTFILE_NAME = "grassd.prom"


def state_dir_textfile(state_dir: Path) -> Path:
    """The textfile inside the state directory: ``state_dir/metrics/grassd.prom``."""
    return Path(state_dir) / "metrics" / TEXTFILE_NAME


def textfile_path(configured: Path | None, state_dir: Path,
                  debian_dir: Path = DEBIAN_TEXTFILE_DIR) -> Path:
    """Where the metrics go: ``configured`` (``[metrics] textfile``) when set, else
    ``debian_dir/grassd.prom`` when that directory exists, else :func:`state_dir_textfile`."""
    if configured is not None:
        return Path(configured)
    if debian_dir.is_dir():
        return debian_dir / TEXTFILE_NAME
    return state_dir_textfile(state_dir)
