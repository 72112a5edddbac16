"""Run logs: one directory per run (``run.yaml``, ``config.yaml``, ``samples.csv``, CAN traffic).

:mod:`~cdcr_ctl.runlog.writer` writes them off the real-time path, :mod:`~cdcr_ctl.runlog.reader`
loads them (partial logs included), :mod:`~cdcr_ctl.runlog.plots` draws them. Column names are
defined once in :mod:`~cdcr_ctl.runlog.columns`. Plots import matplotlib: import
``cdcr_ctl.runlog.plots`` explicitly where they are needed.
"""

from cdcr_ctl.runlog.columns import LOOP_EXTRA_COLUMNS, sample_columns
from cdcr_ctl.runlog.reader import Run, load_run
from cdcr_ctl.runlog.writer import (
    LogStats,
    RunLogFactory,
    RunLogWriter,
    RunMetadata,
    can_log_path,
    new_run_dir,
)

__all__ = [
    "LOOP_EXTRA_COLUMNS",
    "LogStats",
    "Run",
    "RunLogFactory",
    "RunLogWriter",
    "RunMetadata",
    "can_log_path",
    "load_run",
    "new_run_dir",
    "sample_columns",
]
