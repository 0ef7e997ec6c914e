"""Commit a calibration run, in this order: the JSON report and PNG plot (atomic writes), the
controllers' own tables (``[tables] granularity`` "controller"/"pixel"), the history row
``ok`` with the table, then the push to every controller. A report that cannot be written
(full or read-only disk) fails the run and the previous table stays active."""

from __future__ import annotations

import contextlib
import logging
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any

from grassd.daemon.core.calibration.result import CalibrationResult
from grassd.daemon.core.config.settings import Config
from grassd.daemon.core.hardware.fleet import Fleet, table_checksum
from grassd.daemon.core.runtime.push_outcomes import PushOutcomes
from grassd.daemon.core.runtime.young_garbage import freed_when_done
from grassd.daemon.core.store.atomic import (
    atomic_save_figure,
    atomic_write_json,
    describe_write_error,
)
from grassd.daemon.core.store.history import History
from grassd.daemon.core.store.layout import report_stem

log = logging.getLogger(__name__)


def commit_run(run_id: int, result: CalibrationResult, *,
               cfg: Config, history: History, fleet: Fleet, reports_dir: Path,
               outcomes: PushOutcomes, stop: threading.Event,
               progress: Callable[[str], None],
               committed: Callable[[int], None]) -> dict[str, Any]:
    """Commit run ``run_id`` with ``result`` and push its table(s) to ``fleet`` (stopping
    between controllers once ``stop`` is set); ``committed(run_id)`` is called once the
    history row is ``ok``, before the push. Returns the run's outcome: ``{"status": "ok",
    ...}`` with table id and CRC (of the uint16 micrometre table), metrics, report and plot
    paths and the controllers' push reports; or ``{"status": "failed", "transient": True,
    ...}`` when the report could not be written."""
    cal = cfg.calibration
    metrics = result.metrics(cal.r2_goal, cal.target_de00)
    crc = table_checksum(result.lengths_um)
    # a table per controller ([tables] granularity "controller"/"pixel"), else one for all
    own = result.controller_tables
    own_crcs = result.controller_crcs() if own else {}
    base = reports_dir / report_stem(run_id)
    report = {"run_id": run_id, "table_id": run_id, "table_crc": crc, "metrics": metrics,
              **result.report()}
    try:
        report_path = atomic_write_json(base.with_suffix(".json"), report)
        with freed_when_done():  # the figure's cycles, not left to the next full collection
            plot_path = atomic_save_figure(base.with_suffix(".png"), result.figure())
    except OSError as exc:  # full / read-only disk: the previous table stays active
        with contextlib.suppress(OSError):
            base.with_suffix(".json").unlink(missing_ok=True)
        msg = (describe_write_error(exc, reports_dir)
               + "; the previous table stays active")
        log.error("run %d not committed: %s", run_id, msg)
        history.finish_run(run_id, "failed", error=msg)
        return {"status": "failed", "run_id": run_id, "error": msg, "transient": True}
    if result.ccm is not None and result.ccm_source == "bundle":
        history.set_meta("ccm", result.ccm.matrix.tolist())
    if own:  # before the run becomes the current table
        history.record_run_tables(run_id, own, own_crcs)
    history.finish_run(run_id, "ok", metrics=metrics, lengths_um=result.lengths_um,
                       table_id=run_id, table_crc=crc, report_path=report_path,
                       plot_path=plot_path)
    committed(run_id)
    progress(f"pushing table {run_id} to {len(cfg.controllers)} controller(s)")
    reports = fleet.push(own or result.lengths_um, run_id, stop=stop,
                         fallback=result.lengths_um)
    for r in reports:
        outcomes.record(r, run_id, "push")
    log.info("run %d committed: R^2 %.5f, max deviation %.3f dE00, %d/%d controllers",
             run_id, metrics["r2_closed_loop"] or metrics["r2_after_fit"] or 0,
             metrics["max_dev_de00"] or 0,
             sum(r.ok for r in reports), len(cfg.controllers))
    return {"status": "ok", "run_id": run_id, "table_id": run_id, "table_crc": crc,
            "controller_crcs": own_crcs,
            "metrics": metrics, "report": str(report_path), "plot": str(plot_path),
            "controllers": [r.__dict__ for r in reports]}
