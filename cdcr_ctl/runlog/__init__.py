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
the module they come from is imported on their first use (:func:`__getattr__`). Code of the
package imports them from their modules.
"""

from __future__ import annotations

from typing import Any

from cdcr_ctl.runlog.columns import LOOP_EXTRA_COLUMNS, sample_columns

#: The public names defined in the package's heavier modules, imported on first use.
_READER_NAMES = ("Run", "load_run")
_WRITER_NAMES = ("LogStats", "RunLogWriter", "RunMetadata", "can_log_path", "new_run_dir")
_FACTORY_NAMES = ("RunLogFactory",)


def __getattr__(name: str) -> Any:
    """A public name of :data:`_READER_NAMES`, :data:`_WRITER_NAMES` or :data:`_FACTORY_NAMES`
    from its module (imported now, once; the name is then a plain attribute of the package)."""
    if name in _READER_NAMES:
        from cdcr_ctl.runlog import reader as module
    elif name in _WRITER_NAMES:
        from cdcr_ctl.runlog import writer as module
    elif name in _FACTORY_NAMES:
        from cdcr_ctl.runlog.writer import factory as module
    else:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(module, name)
    globals()[name] = value
    return value


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
