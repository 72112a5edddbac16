"""The run directory's files and names: where a run goes (``run_dir_name``, ``new_run_dir``), the
file names, ``run.yaml``'s metadata and reserve, the row counters, and the atomic and in-place
writes the writer uses (a full disk still leaves whole files).
"""

from __future__ import annotations

import contextlib
import errno
import logging
import os
import re
import tempfile
from collections.abc import Mapping
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import IO, Any, Self

from cdcr_ctl import __version__
from cdcr_ctl.errors import RigError

# The writers log under the name they had when they were one module.
_log = logging.getLogger("cdcr_ctl.runlog.writer")

SAMPLES_CSV = "samples.csv"
CONFIG_YAML = "config.yaml"
EFFECTIVE_CONFIG_YAML = "config_effective.yaml"
#: Names the drives layer may use for the raw CAN traffic (python-can ASCWriter / BLFWriter).
CAN_LOG_NAMES = ("can.asc", "can.blf")
#: Written into ``run.yaml`` as ``format``.
FORMAT = "cdcr-ctl-runlog/1"
#: Bytes ``run.yaml`` is padded to beyond its first text when a run starts: the end of the run
#: (outcome, reason, counters, write error) is later written over this reserved space when the
#: disk is full, so the file still says how the run ended.
RUN_YAML_RESERVE_BYTES = 8192
#: Longest reason or write error kept in ``run.yaml`` (characters), so the end fits the reserve.
ENDED_TEXT_MAX = 1500


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


def check_log_dir(base_dir: str | Path) -> Path:
    """Make sure run directories can be created below ``base_dir``: create it if missing, then
    create and remove a probe directory in it. Returns it; raises :class:`RigError` naming the
    path otherwise (a daemon checks this at start rather than fail the first run)."""
    base = Path(base_dir)
    try:
        base.mkdir(parents=True, exist_ok=True)
        probe = Path(tempfile.mkdtemp(prefix=".probe-", dir=base))
        probe.rmdir()
    except OSError as exc:
        raise RigError(
            f"{base}: the run-log directory is not writable: {exc.strerror or exc} "
            "(set logging.directory in the rig config, or run where ./runs can be created)"
        ) from exc
    return base


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


class WriterBase:
    """What the thread and the process run-log writers share: the CAN log's path in the run
    directory, and the context manager (leaving the block closes the run: ``closed``, or
    outcome ``error`` naming the exception that left it)."""

    run_dir: Path
    samples_path: Path
    metadata: RunMetadata
    _overflow: str | None

    def _trip_full(self, store: str, rows: int, behind: str) -> bool:
        """``on_full="trip"`` with the rows' ``store`` (``queue``, ``ring``) full at ``rows``:
        record :attr:`overflow` (once) naming the writer that fell ``behind``. False: the row
        is refused."""
        if self._overflow is None:
            rate = self.metadata.rate_hz
            span = f" = {rows / rate:.3g} s at {rate:g} Hz" if rate else ""
            self._overflow = (
                f"{self.samples_path}: run-log {store} full ({rows} rows{span}): the {behind} "
                "fell behind the loop; rows from here on are not logged"
            )
            _log.error("run log: %s", self._overflow)
        return False

    @property
    def overflow(self) -> str | None:
        """Text naming the run log and its queue (or ring) once a row was refused because it
        was full (``on_full="trip"``: the loop trips ``log_overflow``), else None."""
        return self._overflow

    def can_log_path(self, fmt: str = "asc") -> Path:
        """Path reserved for the raw CAN traffic of this run."""
        return can_log_path(self.run_dir, fmt)

    def close(self, reason: str, outcome: str | None = None, wait: bool = True) -> None:
        raise NotImplementedError

    def __enter__(self) -> Self:
        return self

    def __exit__(self, exc_type: Any, exc: Any, tb: Any) -> None:
        if exc is None:
            self.close("closed")
        else:
            self.close(f"{type(exc).__name__}: {exc}", outcome="error")
