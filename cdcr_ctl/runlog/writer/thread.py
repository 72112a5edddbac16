"""The run-log writer and its thread: the loop queues row objects (no lock, no I/O), a thread
drains the queue in batches, writes, flushes and fsyncs them, and closes the run; a write error
stops the log without raising into the loop. File formats are in
:mod:`cdcr_ctl.runlog.writer.formats`, file names and atomic writes in
:mod:`cdcr_ctl.runlog.writer.files`.
"""

from __future__ import annotations

import atexit
import collections
import contextlib
import logging
import os
import threading
import time
import weakref
from collections.abc import Callable, Iterable, Mapping, Sequence
from pathlib import Path
from typing import IO, Any

from cdcr_ctl.errors import RigError
from cdcr_ctl.runlog.columns import LOOP_EXTRA_COLUMNS, sample_columns
from cdcr_ctl.runlog.mcap_sink import RUN_YAML
from cdcr_ctl.runlog.writer.files import (
    CONFIG_YAML,
    RUN_YAML_RESERVE_BYTES,
    SAMPLES_CSV,
    LogStats,
    RunMetadata,
    WriterBase,
    _default_opener,
    _file_id,
    _padded,
    _write_atomic,
    _write_atomic_bytes,
    new_run_dir,
    utc_now_iso,
)
from cdcr_ctl.runlog.writer.formats import RunFileFormats

# The writer logs under the name it had when it was one module.
log = logging.getLogger("cdcr_ctl.runlog.writer")

#: Period at which the writer thread drains the queue (s).
DRAIN_INTERVAL_S = 0.05
#: Default bound of the row queue (rows): 10 s of a 1 kHz loop.
DEFAULT_QUEUE_ROWS = 10_000
#: What a full queue does to a row: ``trip`` refuses it and records ``overflow`` (real time:
#: the loop must never wait; it trips ``log_overflow``), ``wait`` blocks the writing thread until
#: the writer has made room (the loop on simulated time: no row lost).
ON_FULL = ("trip", "wait")
#: Poll period of a loop waiting for room in the queue (s).
WAIT_POLL_S = 0.001
#: Rows formatted and written per write call.
BATCH_ROWS = 2_000
#: How long ``close(wait=True)`` waits for the writer thread to finish (s).
CLOSE_TIMEOUT_S = 30.0

FileOpener = Callable[[Path], IO[bytes]]
#: Makes a second sink beside ``samples.csv`` (e.g. :mod:`cdcr_ctl.runlog.mcap_sink`):
#: ``factory(run_dir, columns, files)`` with ``files`` the config copies (name -> text). The sink
#: has ``write_rows(rows)``, ``flush()``, ``fileno()`` and ``close(run_yaml, ok)``, all called
#: from the writer thread (``flush`` + fsync every ``fsync_every_s``).
SecondSinkFactory = Callable[[Path, list[str], dict[str, str]], Any]


_OPEN_WRITERS: weakref.WeakSet[RunLogWriter] = weakref.WeakSet()


@atexit.register
def _close_open_writers() -> None:
    """An interpreter exit closes any run log left open (outcome ``aborted``)."""
    for writer in list(_OPEN_WRITERS):
        writer.close("process exit with the log still open", outcome="aborted")


def check_settings(
    columns: Sequence[str],
    fsync_every_s: float,
    max_queued_rows: int,
    drain_interval_s: float,
    on_full: str,
) -> list[str]:
    """A writer's settings checked (ValueError naming the one that is off); the columns as a
    list."""
    if fsync_every_s <= 0 or max_queued_rows < 1 or drain_interval_s <= 0:
        raise ValueError("fsync_every_s, max_queued_rows and drain_interval_s must be > 0")
    if on_full not in ON_FULL:
        raise ValueError(f"on_full {on_full!r}: use one of {ON_FULL}")
    cols = list(columns)
    if len(set(cols)) != len(cols) or not cols:
        raise ValueError("columns must be a non-empty list of distinct names")
    return cols


class RunLogWriter(RunFileFormats, WriterBase):
    """Writes one run directory. Use as a context manager or call :meth:`close`.

    ``run_dir`` must not exist yet or be empty (see :meth:`create` for a fresh one).
    ``columns`` is the CSV header (see :func:`~cdcr_ctl.runlog.columns.sample_columns`).
    ``require_empty`` False skips that check (the writer process: its parent checked, and the
    CAN log may already be open beside it). ``files_made``: the config copies, ``run.yaml`` and
    ``samples.csv`` with its header were made by :meth:`make_start_files` (the writer process's
    parent); this writer appends to ``samples.csv``. ``yield_gil`` False: the writer thread never
    gives up the GIL mid-batch (the writer process: no real-time thread there to wait for it).
    ``config_text`` is copied to ``config.yaml``; ``extra_files`` maps further file names in the
    run directory to their text. ``opener`` opens ``samples.csv`` for binary writing (tests inject
    failing files). ``on_failure(text)`` is called once, from the writer thread, on a write error.

    Raises :class:`RigError` naming the path if the directory or its first files cannot be
    written; after that, nothing raises.
    """

    def __init__(
        self,
        run_dir: str | Path,
        columns: Sequence[str],
        metadata: RunMetadata,
        *,
        config_text: str | None = None,
        config_source: str = "",
        extra_files: Mapping[str, str] | None = None,
        fsync_every_s: float = 0.5,
        max_queued_rows: int = DEFAULT_QUEUE_ROWS,
        on_failure: Callable[[str], None] | None = None,
        opener: FileOpener = _default_opener,
        drain_interval_s: float = DRAIN_INTERVAL_S,
        second_sink: SecondSinkFactory | None = None,
        require_empty: bool = True,
        on_full: str = "trip",
        files_made: bool = False,
        yield_gil: bool = True,
    ) -> None:
        cols = check_settings(columns, fsync_every_s, max_queued_rows, drain_interval_s, on_full)
        self.on_full = on_full
        self._overflow: str | None = None
        self._waits = 0
        self._set_start(run_dir, cols, metadata, config_text, config_source, extra_files)
        self.fsync_every_s = float(fsync_every_s)
        self.max_queued_rows = int(max_queued_rows)
        self._drain_s = float(drain_interval_s)
        self._on_failure = on_failure
        self._colset = frozenset(self.columns)
        if not yield_gil:
            self._yield_every = 0

        # Counters: ``_queued``/``_dropped`` only by the writing thread, the rest by the writer
        # thread, so none needs a lock.
        self._queue: collections.deque[Any] = collections.deque()
        self._queued = 0
        self._dropped = 0
        self._written = 0
        self._lost = 0
        self._fsyncs = 0
        self._bytes = 0
        self._failure: str | None = None
        self._error: BaseException | None = None
        self._closing = False
        self._ended: dict[str, Any] | None = None
        self._warned_keys = False
        self._stop_evt = threading.Event()
        self._done_evt = threading.Event()

        self._file: IO[bytes] | None = None
        self._second: Any = None
        try:
            self.run_dir.mkdir(parents=True, exist_ok=True)
            if require_empty and any(self.run_dir.iterdir()):
                raise RigError(f"{self.run_dir}: run directory is not empty")
            if files_made:
                # The loop's process made them (ProcessRunLogWriter): write on after the header.
                self._dir_id = _file_id(os.stat(self.run_dir))
                self._file = open(self.samples_path, "ab")  # noqa: SIM115 - closed at the end
                self._bytes = self._file.tell()
            else:
                self._file = self._make_start_files(config_text, extra_files, opener)
            if second_sink is not None:
                files = {CONFIG_YAML: config_text} if config_text is not None else {}
                files.update(extra_files or {})
                self._second = second_sink(self.run_dir, self.columns, files)
                if not yield_gil and hasattr(self._second, "yield_every"):
                    self._second.yield_every = 0
        except OSError as exc:
            if self._file is not None:
                with contextlib.suppress(Exception):
                    self._file.close()
            raise RigError(f"{self.run_dir}: cannot start the run log: {exc}") from exc

        self._thread = threading.Thread(
            target=self._run, name=f"runlog:{self.run_dir.name}", daemon=True
        )
        self._thread.start()
        _OPEN_WRITERS.add(self)

    # ------------------------------------------------------------------ construction helpers
    def _set_start(
        self,
        run_dir: str | Path,
        columns: list[str],
        metadata: RunMetadata,
        config_text: str | None,
        config_source: str,
        extra_files: Mapping[str, str] | None,
    ) -> None:
        """The run's directory, columns and metadata, and the files it starts with."""
        self.run_dir = Path(run_dir)
        self.columns = columns
        self.metadata = metadata
        self.samples_path = self.run_dir / SAMPLES_CSV
        self._config_source = config_source
        self._files = [CONFIG_YAML] if config_text is not None else []
        self._files += list(extra_files or {})

    def _make_start_files(
        self,
        config_text: str | None,
        extra_files: Mapping[str, str] | None,
        opener: FileOpener = _default_opener,
    ) -> IO[bytes]:
        """The files a run starts with: the config copies, ``run.yaml`` (the space its end
        needs reserved) and ``samples.csv`` with its header, flushed and fsynced. Returns the
        open ``samples.csv``. Raises OSError."""
        if config_text is not None:
            _write_atomic(self.run_dir / CONFIG_YAML, config_text)
        for name, text in (extra_files or {}).items():
            _write_atomic(self.run_dir / name, text)
        first = self._run_yaml()
        # Reserve the space the end of the run needs (see RUN_YAML_RESERVE_BYTES).
        reserved = _padded(first, len(first.encode("utf-8")) + RUN_YAML_RESERVE_BYTES)
        _write_atomic_bytes(self.run_dir / RUN_YAML, reserved)
        self._dir_id = _file_id(os.stat(self.run_dir))
        f = self._file = opener(self.samples_path)
        header = self._encode([self.columns], raw=True)
        f.write(header)
        f.flush()
        self._fsync()
        self._bytes += len(header)
        return f

    @classmethod
    def make_start_files(
        cls,
        run_dir: str | Path,
        columns: Sequence[str],
        metadata: RunMetadata,
        *,
        config_text: str | None,
        config_source: str,
        extra_files: Mapping[str, str] | None,
        fsync_every_s: float,
    ) -> None:
        """What the constructor writes first, without a writer thread (the loop's process
        before a writer process takes the run over with ``files_made=True``), from the
        constructor's arguments of the same names. Raises OSError."""
        w = cls.__new__(cls)
        w._set_start(run_dir, list(columns), metadata, config_text, config_source, extra_files)
        w.fsync_every_s = float(fsync_every_s)
        w._ended, w._bytes, w._fsyncs, w._file = None, 0, 0, None
        try:
            w._make_start_files(config_text, extra_files)
        finally:
            if w._file is not None:
                w._file.close()

    @classmethod
    def create(
        cls,
        base_dir: str | Path,
        metadata: RunMetadata,
        n_segments: int,
        n_cables: int,
        extra_columns: Iterable[str] = LOOP_EXTRA_COLUMNS,
        **kwargs: Any,
    ) -> RunLogWriter:
        """A writer in a new directory below ``base_dir`` named after the start time and
        ``metadata.name``, with the standard columns for ``n_segments`` and ``n_cables``."""
        run_dir = new_run_dir(base_dir, metadata.name)
        cols = sample_columns(n_segments, n_cables, extra_columns)
        return cls(run_dir, cols, metadata, **kwargs)

    # ------------------------------------------------------------------ real-time side
    def write(self, row: Mapping[str, Any] | Sequence[Any]) -> bool:
        """Queue one row; never raises, never blocks unless ``on_full="wait"`` and the queue is
        full. Returns False if the row was dropped.

        ``row`` is a mapping column -> value (missing columns are empty fields; unknown keys are
        ignored and logged once) or a sequence in column order. Values: float/int/numpy
        scalars, str, None/NaN (empty). The row object must not be mutated afterwards.
        Call from one thread (the loop's): the counters are not locked.
        """
        if self._closing or self._failure is not None:
            self._dropped += 1
            return False
        if len(self._queue) >= self.max_queued_rows and not self._room():
            self._dropped += 1
            return False
        self._queue.append(row)
        self._queued += 1
        return True

    def _room(self) -> bool:
        """The queue is full. ``on_full="wait"`` (the loop on simulated time): wait until the
        writer thread has taken rows (True) or failed or ended (False). ``on_full="trip"``
        (real time): never wait; record :attr:`overflow` (False)."""
        if self.on_full != "wait":
            return self._trip_full("queue", self.max_queued_rows, "writer thread")
        self._waits += 1
        while len(self._queue) >= self.max_queued_rows:
            if self._failure is not None or self._done_evt.is_set():
                return False
            time.sleep(WAIT_POLL_S)
        return True

    @property
    def waits(self) -> int:
        """Rows the loop waited for room for (``on_full="wait"``)."""
        return self._waits

    @property
    def failure(self) -> str | None:
        """Text of the write error that stopped this log (file and cause), or None."""
        return self._failure

    @property
    def error(self) -> BaseException | None:
        """The exception behind :attr:`failure`."""
        return self._error

    @property
    def closed(self) -> bool:
        """True once the writer thread has finished (everything written, run.yaml updated)."""
        return self._done_evt.is_set()

    @property
    def stats(self) -> LogStats:
        return LogStats(
            self._queued, self._written, self._dropped, self._lost, self._fsyncs, self._bytes
        )

    @property
    def can_tap(self) -> Any:
        """A python-can listener feeding the second sink's CAN channel, or None."""
        return getattr(self._second, "can_tap", None)

    def close(self, reason: str, outcome: str | None = None, wait: bool = True) -> None:
        """End the run log: drain the queue, fsync, record ``outcome``/``reason`` in run.yaml.

        ``outcome`` says how the run ended (``completed``, ``stopped``, ``tripped``, ...; default
        ``closed``), ``reason`` why. With ``wait=False`` the writer thread finishes on its own
        (use that from the real-time loop) and :meth:`wait_closed` waits for it. A second call
        changes nothing. Never raises.
        """
        if not self._closing:
            self._ended = {
                "outcome": outcome or "closed",
                "reason": str(reason),
                "end_utc": utc_now_iso(),
            }
            self._closing = True
            self._stop_evt.set()
        if wait:
            self.wait_closed(CLOSE_TIMEOUT_S)

    def wait_closed(self, timeout_s: float | None = None) -> bool:
        """Wait until the writer thread has finished after :meth:`close`; False on timeout."""
        return self._done_evt.wait(timeout_s)

    # ------------------------------------------------------------------ writer thread
    def _run(self) -> None:
        last_sync = time.monotonic()
        try:
            while True:
                stopping = self._stop_evt.wait(self._drain_s)
                self._drain()
                now = time.monotonic()
                # Synced at the last drain before ``fsync_every_s`` would pass (not the first one
                # after it), so two syncs are at most ``fsync_every_s`` apart when the drains
                # come on time: a SIGKILL loses no more than that (issue #23, acceptance 2).
                due = now - last_sync + self._drain_s >= self.fsync_every_s
                if self._failure is None and (stopping or due):
                    # Stopping: the end (_finish) fsyncs each file once, after its last bytes;
                    # fsyncs here too would only add ~4 ms each to the close's wait.
                    self._sync(fsync=not stopping)
                    last_sync = now
                if stopping:
                    break
        except Exception as exc:  # a bug in here must surface as a log failure, not vanish
            self._fail(exc, "writer thread")
        finally:
            self._finish()

    def _drain(self) -> None:
        q = self._queue
        while q:
            batch = [q.popleft() for _ in range(min(len(q), BATCH_ROWS))]
            if self._failure is not None:
                self._lost += len(batch)
                continue
            data = self._encode(batch)
            try:
                self._file.write(data)
                self._file.flush()
            except (OSError, ValueError) as exc:
                self._lost += len(batch)
                self._fail(exc, "write")
                self._trim_partial_row()
                continue
            self._written += len(batch)
            self._bytes += len(data)
            if self._second is not None:
                try:
                    self._second.write_rows(batch)
                except Exception as exc:  # disk full, a bug: stop the log like a CSV failure
                    self._fail(exc, f"{type(self._second).__name__} write")

    def _fsync(self) -> None:
        try:
            fd = self._file.fileno()
        except (OSError, ValueError, AttributeError):
            return  # not a real file (tests): nothing to sync
        os.fsync(fd)
        self._fsyncs += 1

    def _sync(self, fsync: bool = True) -> None:
        """Close the second sink's chunk, fsync both files (``fsync``), check that they have
        not vanished."""
        try:
            if self._second is not None:
                self._second.flush()
                if fsync:
                    os.fsync(self._second.fileno())
            if fsync:
                self._fsync()
        except (OSError, ValueError) as exc:
            self._fail(exc, "fsync")
            return
        self._check_vanished()

    def _check_vanished(self) -> None:
        """The run directory and ``samples.csv`` still there (else the log fails)."""
        try:
            self._check_present()
        except OSError as exc:
            self._fail(exc, "log")

    def _fail(self, exc: BaseException, what: str) -> None:
        if self._failure is not None:
            return
        cause = getattr(exc, "strerror", None) or str(exc) or type(exc).__name__
        self._error = exc
        self._failure = f"{self.samples_path}: {what} failed: {cause}"
        log.error("run log stopped: %s", self._failure)
        with contextlib.suppress(Exception):
            self._file.close()
        if self._on_failure is not None:
            try:
                self._on_failure(self._failure)
            except Exception:
                log.exception("run log on_failure callback raised")

    def _finish(self) -> None:
        try:
            self._lost += len(self._queue)
            self._queue.clear()
            if self._failure is None:
                try:
                    self._file.flush()
                    self._fsync()
                    self._file.close()
                except (OSError, ValueError) as exc:
                    self._fail(exc, "close")
            if self._ended is None:  # thread ended without close(): only on a bug
                self._ended = {
                    "outcome": "error",
                    "reason": self._failure or "writer stopped",
                    "end_utc": utc_now_iso(),
                }
            run_yaml = self._run_yaml()
            if self._second is not None:
                try:
                    self._second.close(run_yaml, self._failure is None)
                except Exception as exc:
                    log.error("%s: closing %s failed: %s", self.run_dir, self._second, exc)
            self._record_end()
        finally:
            _OPEN_WRITERS.discard(self)
            self._done_evt.set()
