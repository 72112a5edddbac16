"""The writer's file formats: CSV rows of ``samples.csv`` (exact float text), ``run.yaml`` with its
end written atomically or over the reserve, the checks that the run directory and ``samples.csv``
have not vanished, and the cut of a partly written batch.

:class:`RunFileFormats` is a mixin of :class:`~cdcr_ctl.runlog.writer.thread.RunLogWriter`.
"""

from __future__ import annotations

import csv
import errno
import io
import logging
import math
import os
import sys
import time
from collections.abc import Mapping
from dataclasses import asdict
from typing import Any

import yaml

from cdcr_ctl.runlog.mcap_sink import RUN_YAML
from cdcr_ctl.runlog.writer.files import (
    CAN_LOG_NAMES,
    ENDED_TEXT_MAX,
    FORMAT,
    SAMPLES_CSV,
    _file_id,
    _overwrite_in_place,
    _write_atomic,
)

# The writer logs under the name it had when it was one module.
log = logging.getLogger("cdcr_ctl.runlog.writer")

#: Rows formatted between two voluntary releases of the GIL by the writer thread (each row is
#: ~20 µs of Python; without the release a 1 kHz loop thread waited up to ~2 ms for the GIL).
YIELD_EVERY_ROWS = 8


_repr = float.__repr__


def _cell(value: Any) -> str:
    """One CSV field: exact float text (``repr``), empty for None/NaN, text without newlines.

    numpy's bool and integer scalars as Python's. numpy is not imported for that (the writer
    process runs without it): a numpy scalar exists only once numpy is loaded, so it is looked
    up in ``sys.modules``."""
    if value is None:
        return ""
    if isinstance(value, str):
        return value.replace("\r", " ").replace("\n", " ")
    np = sys.modules.get("numpy")
    if isinstance(value, bool) or (np is not None and isinstance(value, np.bool_)):
        return "1" if value else "0"
    if isinstance(value, int) or (np is not None and isinstance(value, np.integer)):
        return str(int(value))
    try:
        f = float(value)
    except (TypeError, ValueError):
        return str(value).replace("\r", " ").replace("\n", " ")
    return "" if math.isnan(f) else repr(f)


def csv_line(cells: list[str]) -> str | None:
    """The CSV line (``\\n`` at its end) of ``cells`` when no field needs quoting, as the
    ``csv`` module writes it: no delimiter, quote, CR or LF in any field, and not one empty
    field alone (which it quotes); else None. ~0.5 us a row against ~7 us for ``writerow``
    (the floats' text never needs quoting; a test holds the two equal)."""
    line = ",".join(cells)
    if (
        line.count(",") != len(cells) - 1
        or '"' in line
        or "\n" in line
        or "\r" in line
        or line == ""
    ):
        return None
    return line + "\n"


class RunFileFormats:
    """CSV rows, run.yaml and vanish checks (mixin of the run-log writer)."""

    #: Rows between two releases of the GIL while encoding (0: never, see ``yield_gil`` of
    #: :class:`~cdcr_ctl.runlog.writer.thread.RunLogWriter`).
    _yield_every = YIELD_EVERY_ROWS

    def _encode(self, rows: list[Any], raw: bool = False) -> bytes:
        """CSV text of ``rows``. Gives up the GIL every :data:`YIELD_EVERY_ROWS` rows so the
        real-time thread never waits long for it while a batch is formatted. A row none of
        whose fields needs quoting (:func:`csv_line`) is joined directly, else written by the
        ``csv`` module."""
        buf = io.StringIO()
        writerow = csv.writer(buf, lineterminator="\n").writerow
        write = buf.write
        cols, every = self.columns, self._yield_every
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
            cells = [(_repr(v) if v == v else "") if type(v) is float else _cell(v) for v in values]
            line = csv_line(cells)
            if line is None:
                writerow(cells)
            else:
                write(line)
            if every and n % every == 0:
                time.sleep(0)
        return buf.getvalue().encode("utf-8")

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
                # The raw CAN traffic file the drives layer wrote into this run (None: none,
                # e.g. ``can.log_traffic: false``); at the start it may not be there yet.
                "can_log": next((n for n in CAN_LOG_NAMES if (self.run_dir / n).is_file()), None),
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
