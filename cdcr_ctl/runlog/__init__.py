"""Run logs: one directory per run (``run.yaml``, ``config.yaml``, ``samples.csv``, ``run.mcap``,
CAN traffic).

:mod:`~cdcr_ctl.runlog.writer` writes them off the real-time path (``run.mcap`` through its second
sink, :mod:`~cdcr_ctl.runlog.mcap_sink`), :mod:`~cdcr_ctl.runlog.reader` loads either format
(partial logs included; :mod:`~cdcr_ctl.runlog.mcap_reader`), :mod:`~cdcr_ctl.runlog.export` writes
CSV, Parquet and candump copies, :mod:`~cdcr_ctl.runlog.live` serves the channels
(:mod:`~cdcr_ctl.runlog.streams`) live, :mod:`~cdcr_ctl.runlog.plots` draws them. Column names are
defined once in :mod:`~cdcr_ctl.runlog.columns`. Plots import matplotlib: import
``cdcr_ctl.runlog.plots`` explicitly where they are needed.

Importing the package imports only :mod:`~cdcr_ctl.runlog.columns`: the run-log writer process
(``cdcr_ctl.runlog.writer.child``) starts inside it and must not pay for the reader (mcap's
reader, numpy) or the loop's side of the writer (numpy, python-can). The package's other public
names (``load_run``, ``Run``, ``RunLogWriter``, ``RunLogFactory`` ...) are still its attributes:
the module they come from is imported on their first use (:mod:`cdcr_ctl.firstuse`). Code of the
package imports them from their modules.
"""

from __future__ import annotations

from cdcr_ctl.firstuse import first_use
from cdcr_ctl.runlog.columns import LOOP_EXTRA_COLUMNS, sample_columns

#: The public names defined in the package's heavier modules -> their module (imported on first
#: use, :mod:`cdcr_ctl.firstuse`).
LAZY = {
    **dict.fromkeys(("Run", "load_run"), "cdcr_ctl.runlog.reader"),
    **dict.fromkeys(
        ("LogStats", "RunLogWriter", "RunMetadata", "can_log_path", "new_run_dir"),
        "cdcr_ctl.runlog.writer",
    ),
    "RunLogFactory": "cdcr_ctl.runlog.writer.factory",
}
__getattr__ = first_use(globals(), LAZY)

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
