"""Commit a calibration run, in this order: the JSON report and PNG plot (atomic writes), the
controllers' own tables (``[tables] granularity`` "controller"/"pixel"), then the history row
``ok`` with the table. The commit makes the run's
:class:`~grassd.daemon.core.hardware.desired_tables.DesiredTables` (every table validated and
CRC'd here, once); the push that follows is reconcile's
(:mod:`grassd.daemon.core.runtime.reconcile`). A report that cannot be written (full or
read-only disk) fails the run and the previous table stays active."""

from __future__ import annotations

import contextlib
import logging
from pathlib import Path

from grassd.calib.ccm import ColourCorrection
from grassd.calib.errors import CalibError
from grassd.daemon.core.calibration.result import CalibrationResult
from grassd.daemon.core.config.settings import Config
from grassd.daemon.core.hardware.desired_tables import DesiredTables
from grassd.daemon.core.runtime.outcome import CommittedTable, RunOutcome, RunStatus
from grassd.daemon.core.runtime.young_garbage import freed_when_done
from grassd.daemon.core.store.atomic import (
    atomic_save_figure,
    atomic_write_json,
    describe_write_error,
)
from grassd.daemon.core.store.history import History
from grassd.daemon.core.store.layout import report_stem

log = logging.getLogger(__name__)

#: The history's meta key of the colour correction a run with a checker RAW fitted.
CCM_META = "ccm"


def last_ccm(history: History) -> ColourCorrection | None:
    """The colour correction the last committed run with a checker RAW fitted, for runs
    without one; None when there is none, or when what is stored cannot be read (logged:
    the run then applies no correction)."""
    stored = history.get_meta(CCM_META)
    if stored is None:
        return None
    try:
        return ColourCorrection.from_json(stored)
    except (CalibError, TypeError, ValueError) as exc:
        log.warning("the stored colour correction cannot be read (%s): this run applies none; "
                    "a bundle with a checker RAW fits a new one", exc)
        return None


def commit_run(run_id: int, result: CalibrationResult, *, cfg: Config, history: History,
               reports_dir: Path) -> tuple[RunOutcome, DesiredTables | None]:
    """Commit run ``run_id`` with ``result``: returns the run's outcome and, once its history
    row is ``ok``, the tables every controller should now hold (table id ``run_id``). The
    outcome: OK with the :class:`CommittedTable` (the push reports are added by the push);
    or FAILED and ``transient`` (and no tables) when the report could not be written."""
    cal = cfg.calibration
    metrics = result.metrics(cal.r2_goal, cal.target_de00)
    # a table per controller ([tables] granularity "controller"/"pixel"), else one for all
    desired = DesiredTables.of(run_id, result.lengths_um, result.controller_tables,
                               run_id=run_id)
    assert desired.display is not None
    crc = desired.display.crc
    own_crcs = desired.own_crcs()
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
        return RunOutcome(RunStatus.FAILED, run_id, error=msg, transient=True), None
    if result.ccm is not None and result.ccm_source == "bundle":
        history.set_meta(CCM_META, result.ccm.to_json())
    if desired.own:  # before the run becomes the current table
        history.record_run_tables(run_id, desired.own_lengths(), own_crcs)
    history.finish_run(run_id, "ok", metrics=metrics, lengths_um=result.lengths_um,
                       table_id=run_id, table_crc=crc, report_path=report_path,
                       plot_path=plot_path)
    made = CommittedTable(run_id, crc, metrics, str(report_path), str(plot_path),
                          controller_crcs=own_crcs)
    return RunOutcome(RunStatus.OK, run_id, committed=made), desired
