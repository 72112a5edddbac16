"""Run logs: one directory per run (``run.yaml``, ``config.yaml``, ``samples.csv``, ``run.mcap``,
CAN traffic).

:mod:`~cdcr_ctl.runlog.writer` writes them off the real-time path (``run.mcap`` through its second
sink, :mod:`~cdcr_ctl.runlog.mcap_sink`), :mod:`~cdcr_ctl.runlog.reader` loads either format
(partial logs included; :mod:`~cdcr_ctl.runlog.mcap_reader`), :mod:`~cdcr_ctl.runlog.export` writes
CSV, Parquet and candump copies, :mod:`~cdcr_ctl.runlog.live` serves the channels
(:mod:`~cdcr_ctl.runlog.streams`) live, :mod:`~cdcr_ctl.runlog.plots` draws them. Column names are
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
