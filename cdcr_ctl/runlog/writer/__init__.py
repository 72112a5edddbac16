"""Run-log writer: one directory per run, rows queued by the loop and written by a thread.

A run directory holds

- ``run.yaml``: metadata (start time UTC, rig, design, compensation, loop rate, software version,
  trajectory, counts) and, once the run is closed, ``ended``: outcome, reason, end time and the
  row counters. A run whose ``ended`` is ``null`` did not close (the process died);
- ``config.yaml``: the rig config text as the daemon loaded it (more files may sit beside it,
  e.g. ``config_effective.yaml`` with every default filled in);
- ``samples.csv``: one row per control cycle, columns in :mod:`cdcr_ctl.runlog.columns`;
- ``can.asc`` or ``can.blf``: raw CAN traffic written by the drives layer (name reserved here,
  see :func:`can_log_path`);
- ``run.mcap`` when a ``second_sink`` is given (:mod:`cdcr_ctl.runlog.mcap_sink`): the same rows
  as channels, flushed and fsynced with ``samples.csv``.

Real-time path: :meth:`RunLogWriter.write` appends the row object to a bounded deque and returns
(no lock, no I/O, no formatting). A writer thread wakes every :data:`DRAIN_INTERVAL_S`, formats
the queued rows as CSV, writes and flushes them (a killed process keeps everything flushed) and
fsyncs every ``fsync_every_s`` (a power cut keeps everything fsynced). A write error (disk full,
a file-size limit) stops the writing, cuts a partly written batch back to the last whole row, keeps
what is on disk and is exposed by :attr:`RunLogWriter.failure` and the ``on_failure`` callback;
nothing raises into the caller of ``write``.

This package's namespace holds the thread writer and the file names and formats, what the
run-log writer process (:mod:`~cdcr_ctl.runlog.writer.child`) needs itself; the loop's side of
the process writer (:mod:`~cdcr_ctl.runlog.writer.factory`'s ``RunLogFactory``,
:mod:`~cdcr_ctl.runlog.writer.process`: numpy, python-can) is imported from its module, so the
writer process's start does not pay for it.
"""

from cdcr_ctl.runlog.mcap_sink import RUN_YAML
from cdcr_ctl.runlog.writer.files import (
    CAN_LOG_NAMES,
    CONFIG_YAML,
    EFFECTIVE_CONFIG_YAML,
    ENDED_TEXT_MAX,
    FORMAT,
    RUN_YAML_RESERVE_BYTES,
    SAMPLES_CSV,
    LogStats,
    RunMetadata,
    _default_opener,
    _file_id,
    _fsync_dir,
    _overwrite_in_place,
    _padded,
    _write_atomic,
    _write_atomic_bytes,
    can_log_path,
    new_run_dir,
    run_dir_name,
    utc_now_iso,
)
from cdcr_ctl.runlog.writer.formats import YIELD_EVERY_ROWS, RunFileFormats, _cell, _repr
from cdcr_ctl.runlog.writer.thread import (
    _OPEN_WRITERS,
    BATCH_ROWS,
    CLOSE_TIMEOUT_S,
    DEFAULT_QUEUE_ROWS,
    DRAIN_INTERVAL_S,
    FileOpener,
    RunLogWriter,
    SecondSinkFactory,
    _close_open_writers,
    log,
)

__all__ = [
    "BATCH_ROWS",
    "CAN_LOG_NAMES",
    "CLOSE_TIMEOUT_S",
    "CONFIG_YAML",
    "DEFAULT_QUEUE_ROWS",
    "DRAIN_INTERVAL_S",
    "EFFECTIVE_CONFIG_YAML",
    "ENDED_TEXT_MAX",
    "FORMAT",
    "RUN_YAML",
    "RUN_YAML_RESERVE_BYTES",
    "SAMPLES_CSV",
    "YIELD_EVERY_ROWS",
    "_OPEN_WRITERS",
    "FileOpener",
    "LogStats",
    "RunFileFormats",
    "RunLogWriter",
    "RunMetadata",
    "SecondSinkFactory",
    "_cell",
    "_close_open_writers",
    "_default_opener",
    "_file_id",
    "_fsync_dir",
    "_overwrite_in_place",
    "_padded",
    "_repr",
    "_write_atomic",
    "_write_atomic_bytes",
    "can_log_path",
    "log",
    "new_run_dir",
    "run_dir_name",
    "utc_now_iso",
]
