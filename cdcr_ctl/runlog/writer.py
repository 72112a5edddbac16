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
"""

from __future__ import annotations

import atexit
import collections
import contextlib
import csv
import errno
import io
import logging
import math
import os
import re
import threading
import time
import weakref
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import asdict, dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any

import numpy as np
import yaml

from cdcr_ctl import __version__
from cdcr_ctl.errors import RigError
from cdcr_ctl.runlog.columns import LOOP_EXTRA_COLUMNS, sample_columns
from cdcr_ctl.runlog.mcap_sink import RUN_YAML, McapSinkFactory

if TYPE_CHECKING:
    from cdcr_ctl.config.schema import RigConfig

log = logging.getLogger(__name__)

SAMPLES_CSV = "samples.csv"
CONFIG_YAML = "config.yaml"
EFFECTIVE_CONFIG_YAML = "config_effective.yaml"
#: Names the drives layer may use for the raw CAN traffic (python-can ASCWriter / BLFWriter).
CAN_LOG_NAMES = ("can.asc", "can.blf")
#: Written into ``run.yaml`` as ``format``.
FORMAT = "cdcr-ctl-runlog/1"

#: Period at which the writer thread drains the queue (s).
DRAIN_INTERVAL_S = 0.05
#: Default bound of the row queue (rows): 10 s of a 1 kHz loop.
DEFAULT_QUEUE_ROWS = 10_000
#: Rows formatted and written per write call.
BATCH_ROWS = 2_000
#: Rows formatted between two voluntary releases of the GIL by the writer thread (each row is
#: ~20 µs of Python; without the release a 1 kHz loop thread waited up to ~2 ms for the GIL).
YIELD_EVERY_ROWS = 8
#: How long ``close(wait=True)`` waits for the writer thread to finish (s).
CLOSE_TIMEOUT_S = 30.0
#: Bytes ``run.yaml`` is padded to beyond its first text when a run starts: the end of the run
#: (outcome, reason, counters, write error) is later written over this reserved space when the
#: disk is full, so the file still says how the run ended.
RUN_YAML_RESERVE_BYTES = 8192
#: Longest reason or write error kept in ``run.yaml`` (characters), so the end fits the reserve.
ENDED_TEXT_MAX = 1500

FileOpener = Callable[[Path], IO[bytes]]
#: Makes a second sink beside ``samples.csv`` (e.g. :mod:`cdcr_ctl.runlog.mcap_sink`):
#: ``factory(run_dir, columns, files)`` with ``files`` the config copies (name -> text). The sink
#: has ``write_rows(rows)``, ``flush()``, ``fileno()`` and ``close(run_yaml, ok)``, all called
#: from the writer thread (``flush`` + fsync every ``fsync_every_s``).
SecondSinkFactory = Callable[[Path, list[str], dict[str, str]], Any]


def utc_now_iso() -> str:
    """Current UTC time as ISO 8601 with milliseconds and a ``Z``."""
    return datetime.now(UTC).isoformat(timespec="milliseconds").replace("+00:00", "Z")


def can_log_path(run_dir: str | Path, fmt: str = "asc") -> Path:
    """Where the drives layer writes the raw CAN traffic of a run (``fmt``: ``asc`` or ``blf``)."""
    name = f"can.{fmt}"
    if name not in CAN_LOG_NAMES:
        raise ValueError(f"CAN log format {fmt!r}: use one of {CAN_LOG_NAMES}")
    return Path(run_dir) / name


def run_dir_name(name: str, start: datetime | None = None) -> str:
    """``20240501-142233_planar_bend``: UTC start, then ``name`` reduced to ``[A-Za-z0-9._-]``."""
    start = start or datetime.now(UTC)
    slug = re.sub(r"[^A-Za-z0-9._-]+", "_", name).strip("._") or "run"
    return f"{start.astimezone(UTC):%Y%m%d-%H%M%S}_{slug[:60]}"


def new_run_dir(base_dir: str | Path, name: str, start: datetime | None = None) -> Path:
    """Create and return a fresh run directory below ``base_dir`` (``_2``, ``_3`` ... on a clash).

    Raises :class:`RigError` naming the directory when it cannot be created.
    """
    base = Path(base_dir)
    stem = run_dir_name(name, start)
    try:
        base.mkdir(parents=True, exist_ok=True)
        for n in range(1, 1000):
            path = base / (stem if n == 1 else f"{stem}_{n}")
            try:
                path.mkdir()
            except FileExistsError:
                continue
            return path
    except OSError as exc:
        raise RigError(f"{base}: cannot create a run directory: {exc.strerror or exc}") from exc
    raise RigError(f"{base}: 999 run directories named {stem!r} already exist")


@dataclass(frozen=True)
class RunMetadata:
    """What ``run.yaml`` says about a run besides its end. ``rate_hz`` is the loop rate (Hz)."""

    name: str
    rig: str = ""
    design: str = ""
    compensation: str = ""
    rate_hz: float | None = None
    trajectory: str = ""
    software_version: str = __version__
    start_utc: str = field(default_factory=utc_now_iso)
    extra: Mapping[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class LogStats:
    """Row counters of a writer.

    ``queued``: accepted by :meth:`~RunLogWriter.write`; ``dropped``: refused by it (queue full,
    writer closed or failed); ``written``: on disk (flushed to the OS); ``lost``: accepted but not
    written because of a write error; ``fsyncs``: completed fsyncs; ``bytes``: bytes written.
    No sample was lost when ``dropped == lost == 0`` and ``written == queued`` after close.
    """

    queued: int
    written: int
    dropped: int
    lost: int
    fsyncs: int
    bytes: int

    @property
    def complete(self) -> bool:
        return self.dropped == 0 and self.lost == 0 and self.written == self.queued


_repr = float.__repr__


def _cell(value: Any) -> str:
    """One CSV field: exact float text (``repr``), empty for None/NaN, text without newlines."""
    if value is None:
        return ""
    if isinstance(value, str):
        return value.replace("\r", " ").replace("\n", " ")
    if isinstance(value, bool | np.bool_):
        return "1" if value else "0"
    if isinstance(value, int | np.integer):
        return str(int(value))
    try:
        f = float(value)
    except (TypeError, ValueError):
        return str(value).replace("\r", " ").replace("\n", " ")
    return "" if math.isnan(f) else repr(f)


def _default_opener(path: Path) -> IO[bytes]:
    return open(path, "xb")  # the writer thread owns and closes it


def _fsync_dir(path: Path) -> None:
    with contextlib.suppress(OSError):
        fd = os.open(path, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


def _write_atomic(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` via a temporary file, fsync, rename, fsync the directory.

    A failed write (disk full) removes its temporary file and leaves ``path`` as it was."""
    _write_atomic_bytes(path, text.encode("utf-8"))


def _write_atomic_bytes(path: Path, data: bytes) -> None:
    tmp = path.with_name(path.name + ".tmp")
    try:
        with open(tmp, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise
    _fsync_dir(path.parent)


def _file_id(st: os.stat_result) -> tuple[int, int]:
    return (st.st_dev, st.st_ino)


def _padded(text: str, size: int) -> bytes:
    """``text`` followed by YAML comment lines up to ``size`` bytes (the reserve of run.yaml)."""
    data = text.encode("utf-8")
    if not data.endswith(b"\n"):
        data += b"\n"
    line = b"#" + b" " * 62 + b"\n"  # 64 bytes
    pad = max(size - len(data), 0)
    data += line * (pad // len(line))
    rest = size - len(data)
    if rest > 0:
        data += b"#" * (rest - 1) + b"\n" if rest > 1 else b"\n"
    return data


def _overwrite_in_place(path: Path, text: str) -> None:
    """Write ``text`` over the start of the reserved file ``path`` without growing it (the
    blocks are already the file's: this works on a full disk); pad the rest with comments."""
    size = path.stat().st_size
    data = _padded(text, size)
    if len(data) > size:
        raise OSError(errno.ENOSPC, f"the end of the run needs {len(data)} bytes, {size} reserved")
    fd = os.open(path, os.O_WRONLY)
    try:
        view = memoryview(data)
        while view:
            view = view[os.write(fd, view) :]
        os.fsync(fd)
    finally:
        os.close(fd)


_OPEN_WRITERS: weakref.WeakSet[RunLogWriter] = weakref.WeakSet()


@atexit.register
def _close_open_writers() -> None:
    """An interpreter exit closes any run log left open (outcome ``aborted``)."""
    for writer in list(_OPEN_WRITERS):
        writer.close("process exit with the log still open", outcome="aborted")


class RunLogWriter:
    """Writes one run directory. Use as a context manager or call :meth:`close`.

    ``run_dir`` must not exist yet or be empty (see :meth:`create` for a fresh one).
    ``columns`` is the CSV header (see :func:`~cdcr_ctl.runlog.columns.sample_columns`).
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
    ) -> None:
        if fsync_every_s <= 0 or max_queued_rows < 1 or drain_interval_s <= 0:
            raise ValueError("fsync_every_s, max_queued_rows and drain_interval_s must be > 0")
        self.run_dir = Path(run_dir)
        self.columns = list(columns)
        if len(set(self.columns)) != len(self.columns) or not self.columns:
            raise ValueError("columns must be a non-empty list of distinct names")
        self.metadata = metadata
        self.samples_path = self.run_dir / SAMPLES_CSV
        self.fsync_every_s = float(fsync_every_s)
        self.max_queued_rows = int(max_queued_rows)
        self._drain_s = float(drain_interval_s)
        self._on_failure = on_failure
        self._colset = frozenset(self.columns)
        self._config_source = config_source
        self._files = [CONFIG_YAML] if config_text is not None else []
        self._files += list(extra_files or {})

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
            if any(self.run_dir.iterdir()):
                raise RigError(f"{self.run_dir}: run directory is not empty")
            if config_text is not None:
                _write_atomic(self.run_dir / CONFIG_YAML, config_text)
            for name, text in (extra_files or {}).items():
                _write_atomic(self.run_dir / name, text)
            first = self._run_yaml()
            # Reserve the space the end of the run needs (see RUN_YAML_RESERVE_BYTES).
            reserved = _padded(first, len(first.encode("utf-8")) + RUN_YAML_RESERVE_BYTES)
            _write_atomic_bytes(self.run_dir / RUN_YAML, reserved)
            self._dir_id = _file_id(os.stat(self.run_dir))
            self._file = opener(self.samples_path)
            header = self._encode([self.columns], raw=True)
            self._file.write(header)
            self._file.flush()
            self._fsync()
            self._bytes += len(header)
            if second_sink is not None:
                files = {CONFIG_YAML: config_text} if config_text is not None else {}
                files.update(extra_files or {})
                self._second = second_sink(self.run_dir, self.columns, files)
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
        """Queue one row; never blocks, never raises. Returns False if the row was dropped.

        ``row`` is a mapping column -> value (missing columns are empty fields; unknown keys are
        ignored and logged once) or a sequence in column order. Values: float/int/numpy
        scalars, str, None/NaN (empty). The row object must not be mutated afterwards.
        Call from one thread (the loop's): the counters are not locked.
        """
        if self._closing or self._failure is not None or len(self._queue) >= self.max_queued_rows:
            self._dropped += 1
            return False
        self._queue.append(row)
        self._queued += 1
        return True

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

    def can_log_path(self, fmt: str = "asc") -> Path:
        """Path reserved for the raw CAN traffic of this run."""
        return can_log_path(self.run_dir, fmt)

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

    def __enter__(self) -> RunLogWriter:
        return self

    def __exit__(self, exc_type: Any, exc: Any, tb: Any) -> None:
        if exc is None:
            self.close("closed")
        else:
            self.close(f"{type(exc).__name__}: {exc}", outcome="error")

    # ------------------------------------------------------------------ writer thread
    def _run(self) -> None:
        last_sync = time.monotonic()
        try:
            while True:
                stopping = self._stop_evt.wait(self._drain_s)
                self._drain()
                now = time.monotonic()
                if self._failure is None and (stopping or now - last_sync >= self.fsync_every_s):
                    self._sync()
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

    def _encode(self, rows: list[Any], raw: bool = False) -> bytes:
        """CSV text of ``rows``. Gives up the GIL every :data:`YIELD_EVERY_ROWS` rows so the
        real-time thread never waits long for it while a batch is formatted."""
        buf = io.StringIO()
        writerow = csv.writer(buf, lineterminator="\n").writerow
        cols = self.columns
        for n, row in enumerate(rows, start=1):
            if raw:
                writerow(row)
                continue
            if isinstance(row, Mapping):
                if not self._warned_keys and not self._colset.issuperset(row):
                    self._warned_keys = True
                    unknown = sorted(set(row) - self._colset)
                    log.warning("%s: unknown keys ignored: %s", self.samples_path, unknown)
                values = list(map(row.get, cols))
            else:
                values = list(row)
                if len(values) != len(cols):
                    if not self._warned_keys:
                        self._warned_keys = True
                        log.warning(
                            "%s: a row has %d values for %d columns",
                            self.samples_path,
                            len(values),
                            len(cols),
                        )
                    values = (values + [None] * len(cols))[: len(cols)]
            # Fast path for plain floats (almost every field), _cell for the rest.
            writerow(
                [(_repr(v) if v == v else "") if type(v) is float else _cell(v) for v in values]
            )
            if n % YIELD_EVERY_ROWS == 0:
                time.sleep(0)
        return buf.getvalue().encode("utf-8")

    def _fsync(self) -> None:
        try:
            fd = self._file.fileno()
        except (OSError, ValueError, AttributeError):
            return  # not a real file (tests): nothing to sync
        os.fsync(fd)
        self._fsyncs += 1

    def _sync(self) -> None:
        try:
            if self._second is not None:
                self._second.flush()
                os.fsync(self._second.fileno())
            self._fsync()
        except (OSError, ValueError) as exc:
            self._fail(exc, "fsync")
            return
        try:
            self._check_present()
        except OSError as exc:
            self._fail(exc, "log")

    def _check_present(self) -> None:
        """Raise if the run directory or ``samples.csv`` was deleted or replaced: writing on
        into an unlinked file loses the log as surely as a full disk (checked at every fsync,
        so a vanished log is seen within one ``fsync_every_s``)."""
        try:
            fd = self._file.fileno()
        except (OSError, ValueError, AttributeError):
            fd = None  # not a real file (tests)
        if fd is not None:
            st = os.fstat(fd)
            if st.st_nlink == 0:
                raise OSError(errno.ENOENT, "samples.csv was deleted")
            try:
                on_disk = os.stat(self.samples_path)
            except FileNotFoundError:
                raise OSError(errno.ENOENT, "samples.csv is gone from the run directory") from None
            if _file_id(on_disk) != _file_id(st):
                raise OSError(errno.ESTALE, "samples.csv was replaced by another file")
        try:
            now = _file_id(os.stat(self.run_dir))
        except FileNotFoundError:
            raise OSError(errno.ENOENT, f"run directory {self.run_dir} was deleted") from None
        if now != self._dir_id:
            raise OSError(errno.ESTALE, f"run directory {self.run_dir} was replaced")

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

    def _trim_partial_row(self) -> None:
        """After a failed write (disk full, file-size limit) part of the batch may have reached
        the file: cut it back to the last whole row written, so the file ends on a complete row.
        Truncating frees space, so it works on a full disk; it never grows the file."""
        try:
            size = os.stat(self.samples_path).st_size
            if size > self._bytes:
                os.truncate(self.samples_path, self._bytes)
                log.warning(
                    "%s: cut %d bytes of a partly written batch",
                    self.samples_path,
                    size - self._bytes,
                )
        except OSError as exc:
            log.error("%s: cannot cut the partial row: %s", self.samples_path, exc)

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

    def _record_end(self) -> None:
        """The end of the run into run.yaml: atomically if the disk allows, else over the
        space reserved at the start (a full disk still says how the run ended)."""
        path = self.run_dir / RUN_YAML
        text = self._run_yaml()
        try:
            _write_atomic(path, text)
            return
        except OSError as exc:
            log.warning("%s: atomic write failed (%s); writing into the reserve", path, exc)
        try:
            _overwrite_in_place(path, text)
        except OSError as exc:
            log.error("%s: cannot record the end of the run: %s", path, exc)

    def _run_yaml(self) -> str:
        meta = asdict(self.metadata)
        extra = dict(meta.pop("extra") or {})
        doc: dict[str, Any] = {"format": FORMAT, **meta}
        doc.update(
            {
                "columns": len(self.columns),
                "config": {"files": self._files, "source": self._config_source},
                "samples": SAMPLES_CSV,
                "can_log": list(CAN_LOG_NAMES),
                "fsync_every_s": self.fsync_every_s,
                "extra": extra,
                "ended": None,
            }
        )
        if self._ended is not None:
            s = self.stats
            ended = dict(self._ended)
            ended["reason"] = str(ended["reason"])[:ENDED_TEXT_MAX]
            doc["ended"] = {
                **ended,
                "rows": {
                    "queued": s.queued,
                    "written": s.written,
                    "dropped": s.dropped,
                    "lost": s.lost,
                },
                "write_error": None if self._failure is None else self._failure[:ENDED_TEXT_MAX],
            }
        return yaml.safe_dump(doc, sort_keys=False, allow_unicode=True)


class RunLogFactory:
    """Makes one :class:`RunLogWriter` per run with the rig's metadata and config copy.

    Called as ``factory(name, compensation, trajectory="")`` (the daemon's ``run_sink_factory``).
    ``config_text`` is the rig config file as loaded; ``effective_config`` (optional) the
    validated config with defaults filled, written as ``config_effective.yaml``.
    """

    def __init__(
        self,
        base_dir: str | Path,
        *,
        rig: str,
        design: str,
        rate_hz: float,
        n_segments: int,
        n_cables: int,
        config_text: str | None = None,
        config_source: str = "",
        effective_config: str | None = None,
        fsync_every_s: float = 0.5,
        extra_columns: Sequence[str] = LOOP_EXTRA_COLUMNS,
        max_queued_rows: int = DEFAULT_QUEUE_ROWS,
        on_failure: Callable[[str], None] | None = None,
        mcap: bool = False,
        tip_from_psi: Callable[[Any], Any] | None = None,
    ) -> None:
        self.base_dir = Path(base_dir)
        #: ``run.mcap`` beside ``samples.csv`` (``logging.mcap``); ``tip_from_psi``: the model's
        #: tip of a commanded pose for its ``/tip/model`` channel.
        self.second_sink = McapSinkFactory(tip_from_psi, rate_hz) if mcap else None
        self.rig, self.design, self.rate_hz = rig, design, float(rate_hz)
        self.n_segments, self.n_cables = n_segments, n_cables
        self.config_text, self.config_source = config_text, config_source
        self.effective_config = effective_config
        self.fsync_every_s = fsync_every_s
        self.extra_columns = tuple(extra_columns)
        self.max_queued_rows = max_queued_rows
        self.on_failure = on_failure
        sample_columns(n_segments, n_cables, self.extra_columns)  # fail early on bad names

    @classmethod
    def from_config(
        cls,
        cfg: RigConfig,
        config_path: str | Path,
        *,
        n_segments: int | None = None,
        n_cables: int | None = None,
        base_dir: str | Path | None = None,
        **kwargs: Any,
    ) -> RunLogFactory:
        """Factory for a validated rig config read from ``config_path``.

        The log directory is ``cfg.logging.directory`` (relative to the config file's folder if
        relative) unless ``base_dir`` is given; counts default to the config's segments and
        cables. Raises :class:`RigError` naming the file if the config cannot be re-read.
        """
        path = Path(config_path)
        try:
            text = path.read_text(encoding="utf-8")
        except OSError as exc:
            raise RigError(f"{path}: cannot read the config for the run logs: {exc}") from exc
        if base_dir is None:
            base_dir = Path(cfg.logging.directory)
            if not base_dir.is_absolute():
                base_dir = path.parent / base_dir
        effective = yaml.safe_dump(cfg.model_dump(mode="json"), sort_keys=False)
        return cls(
            base_dir,
            rig=cfg.name,
            design=cfg.design,
            rate_hz=cfg.control.rate_hz,
            n_segments=n_segments or len(cfg.robot.segments),
            n_cables=n_cables or len(cfg.robot.cables),
            config_text=text,
            config_source=str(path.resolve()),
            effective_config=effective,
            fsync_every_s=cfg.logging.fsync_every_s,
            mcap=cfg.logging.mcap,
            **kwargs,
        )

    def __call__(self, name: str, compensation: str, trajectory: str = "") -> RunLogWriter:
        meta = RunMetadata(
            name=name,
            rig=self.rig,
            design=self.design,
            compensation=compensation,
            rate_hz=self.rate_hz,
            trajectory=trajectory or name,
        )
        extra = {EFFECTIVE_CONFIG_YAML: self.effective_config} if self.effective_config else None
        return RunLogWriter.create(
            self.base_dir,
            meta,
            self.n_segments,
            self.n_cables,
            self.extra_columns,
            config_text=self.config_text,
            config_source=self.config_source,
            extra_files=extra,
            fsync_every_s=self.fsync_every_s,
            max_queued_rows=self.max_queued_rows,
            on_failure=self.on_failure,
            second_sink=self.second_sink,
        )
