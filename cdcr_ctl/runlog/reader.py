"""Run-log reader: ``load_run(run_dir) -> Run`` with one numpy array per column.

Tolerant of what a real run leaves behind: column groups may be missing (no load cells, no
tracker: :attr:`Run.groups` says which are present), a process killed mid-write leaves an
incomplete last line (dropped, and said so in :attr:`Run.warnings`), a run that never closed has
``ended: null`` in its ``run.yaml``. Anything else that is wrong (a row with the wrong number of
fields, text in a numeric column, a header without ``t_s``) is a :class:`ConfigError` naming the
file and the line.
"""

from __future__ import annotations

import csv
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from math import nan
from pathlib import Path
from typing import IO, Any

import numpy as np
import yaml

from cdcr_ctl.errors import ConfigError, RigError
from cdcr_ctl.runlog.columns import (
    GROUP_PSI_CMD,
    GROUP_Q_ACT,
    GROUP_Q_CMD,
    GROUP_Q_NOMINAL,
    GROUP_TENSION,
    GROUP_TIP,
    TEXT_COLUMNS,
    TIME,
    TIP_COLUMNS,
    cable_column,
    counts_from_columns,
    group_of,
    phi_cmd,
    theta_cmd,
)
from cdcr_ctl.runlog.mcap_reader import read_mcap
from cdcr_ctl.runlog.mcap_sink import RUN_MCAP
from cdcr_ctl.runlog.writer import CAN_LOG_NAMES, CONFIG_YAML, RUN_YAML, SAMPLES_CSV

#: Rows converted to numpy per chunk while reading (bounds the memory of the text form).
CHUNK_ROWS = 50_000
_TAIL_BLOCK = 65_536


@dataclass
class Run:
    """One run log loaded into memory.

    ``data`` maps each CSV column to an array of length N: float64 (NaN where the field was
    empty) for numeric columns, ``object`` (str) for text columns such as ``event``.
    ``groups`` names the column groups present (see :mod:`cdcr_ctl.runlog.columns`).
    """

    run_dir: Path
    samples_path: Path
    metadata: dict[str, Any]
    columns: list[str]
    data: dict[str, np.ndarray]
    n_segments: int
    n_cables: int
    groups: frozenset[str]
    config_path: Path | None = None
    can_log: Path | None = None
    warnings: list[str] = field(default_factory=list)
    dropped_tail_bytes: int = 0

    def __len__(self) -> int:
        return len(self.data[TIME])

    @property
    def t_s(self) -> np.ndarray:
        """Cycle times (s), shape (N,)."""
        return self.data[TIME]

    @property
    def ended(self) -> dict[str, Any] | None:
        """``run.yaml``'s ``ended`` (outcome, reason, end time, row counts); None if unclosed."""
        ended = self.metadata.get("ended")
        return ended if isinstance(ended, dict) else None

    @property
    def extra_columns(self) -> list[str]:
        """Columns outside the standard groups (``cycle``, ``event``, ...)."""
        return [c for c in self.columns if c != TIME and group_of(c) is None]

    def has(self, group: str) -> bool:
        """Whether any column of ``group`` (e.g. ``"tension"``, ``"tip"``) is present."""
        return group in self.groups

    def column(self, name: str) -> np.ndarray:
        """One column by name; :class:`RigError` naming the file if absent."""
        try:
            return self.data[name]
        except KeyError:
            raise RigError(f"{self.samples_path}: no column {name!r}") from None

    def _stack(self, group: str, names: list[str]) -> np.ndarray:
        if group not in self.groups:
            raise RigError(f"{self.samples_path}: the log has no {group} columns")
        nan = np.full(len(self), np.nan)
        return np.column_stack([self.data.get(n, nan) for n in names])

    def _cables(self, group: str) -> np.ndarray:
        return self._stack(group, [cable_column(group, k) for k in range(1, self.n_cables + 1)])

    def q_nominal(self) -> np.ndarray:
        """Ideal inverse-kinematics displacements (mm), shape (N, K)."""
        return self._cables(GROUP_Q_NOMINAL)

    def q_cmd(self) -> np.ndarray:
        """Sent (compensated) displacements (mm), shape (N, K)."""
        return self._cables(GROUP_Q_CMD)

    def q_act(self) -> np.ndarray:
        """Drive feedback displacements (mm), shape (N, K)."""
        return self._cables(GROUP_Q_ACT)

    def tension(self) -> np.ndarray:
        """Load-cell tensions (N), shape (N, K); NaN where a cable has no cell."""
        return self._cables(GROUP_TENSION)

    def tip(self) -> np.ndarray:
        """Tracked tip in the robot base frame (mm), shape (N, 3); NaN rows where untracked."""
        return self._stack(GROUP_TIP, list(TIP_COLUMNS))

    def theta_cmd(self) -> np.ndarray:
        """Commanded bend angles (rad), shape (N, S)."""
        return self._stack(GROUP_PSI_CMD, [theta_cmd(i) for i in range(1, self.n_segments + 1)])

    def phi_cmd(self) -> np.ndarray:
        """Commanded bending directions (rad), shape (N, S)."""
        return self._stack(GROUP_PSI_CMD, [phi_cmd(i) for i in range(1, self.n_segments + 1)])

    def psi_cmd(self) -> np.ndarray:
        """Commanded (θ, φ) per segment (rad), shape (N, S, 2)."""
        return np.stack((self.theta_cmd(), self.phi_cmd()), axis=-1)


def load_run(path: str | Path) -> Run:
    """Load a run directory, its ``samples.csv`` or its ``run.mcap``.

    A directory is read from ``samples.csv`` when it has one, else from ``run.mcap`` (a run
    logged as MCAP only, or a copy of one); a path to a ``.mcap`` file reads that file. Both
    give the same columns (see :mod:`cdcr_ctl.runlog.mcap_reader`).

    Raises :class:`ConfigError` naming the file and line for corrupt content, and for a missing
    ``samples.csv``. A missing ``run.yaml`` only adds a warning (metadata is then empty).
    """
    p = Path(path)
    if p.suffix == ".mcap" and not p.is_dir():
        return load_mcap_run(p)
    if p.is_dir() and not (p / SAMPLES_CSV).exists() and (p / RUN_MCAP).is_file():
        return load_mcap_run(p / RUN_MCAP)
    run_dir = p.parent if p.name == SAMPLES_CSV and not p.is_dir() else p
    samples = run_dir / SAMPLES_CSV
    warnings: list[str] = []
    metadata = _load_metadata(run_dir / RUN_YAML, warnings)
    columns, data, tail = _load_samples(samples, warnings)
    n_seg, n_cab = counts_from_columns(columns)
    groups = frozenset(g for c in columns if (g := group_of(c)) is not None)
    config = run_dir / CONFIG_YAML
    can_log = next((run_dir / n for n in CAN_LOG_NAMES if (run_dir / n).is_file()), None)
    return Run(
        run_dir=run_dir,
        samples_path=samples,
        metadata=metadata,
        columns=columns,
        data=data,
        n_segments=n_seg,
        n_cables=n_cab,
        groups=groups,
        config_path=config if config.is_file() else None,
        can_log=can_log,
        warnings=warnings,
        dropped_tail_bytes=tail,
    )


def load_mcap_run(path: str | Path) -> Run:
    """Load a run from its MCAP file. Metadata: the file's ``run.yaml`` attachment (written at
    close), else ``run.yaml`` beside the file, else the file's start metadata."""
    p = Path(path)
    run_dir = p.parent
    m = read_mcap(p)
    warnings = list(m.warnings)
    metadata = m.run_yaml() if "run.yaml" in m.attachments else None
    if metadata is None:
        metadata = (
            _load_metadata(run_dir / RUN_YAML, warnings)
            if (run_dir / RUN_YAML).is_file()
            else (m.run_yaml() or {})
        )
    n_seg, n_cab = counts_from_columns(m.columns)
    config = run_dir / CONFIG_YAML
    can_log = next((run_dir / n for n in CAN_LOG_NAMES if (run_dir / n).is_file()), None)
    return Run(
        run_dir=run_dir,
        samples_path=p,
        metadata=metadata,
        columns=m.columns,
        data=m.data,
        n_segments=n_seg,
        n_cables=n_cab,
        groups=frozenset(g for c in m.columns if (g := group_of(c)) is not None),
        config_path=config if config.is_file() else None,
        can_log=can_log,
        warnings=warnings,
    )


def run_closed(run_dir: str | Path) -> bool:
    """True once the writer has closed the run in ``run_dir`` (``run.yaml`` has its ``ended``):
    every row it took is in ``samples.csv``/``run.mcap``. A run's end in the daemon's status
    comes first (the loop never waits for the writer), so a client that reads the log right
    after a run waits for this. A ``run.yaml`` being rewritten reads as not closed yet."""
    try:
        doc = yaml.safe_load((Path(run_dir) / RUN_YAML).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, yaml.YAMLError):
        return False
    return isinstance(doc, dict) and isinstance(doc.get("ended"), dict)


def wait_run_closed(run_dir: str | Path, timeout_s: float, poll_s: float = 0.05) -> bool:
    """Wait up to ``timeout_s`` (wall clock) for :func:`run_closed`; its last answer."""
    end = time.monotonic() + timeout_s
    while not run_closed(run_dir):
        if time.monotonic() >= end:
            return False
        time.sleep(poll_s)
    return True


def _load_metadata(path: Path, warnings: list[str]) -> dict[str, Any]:
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        warnings.append(f"{path}: missing; no run metadata")
        return {}
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(str(path), "", f"cannot read run metadata: {exc}") from exc
    try:
        doc = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"line {mark.line + 1}" if mark else ""
        raise ConfigError(str(path), where, f"YAML syntax error: {exc}") from exc
    if doc is None:
        warnings.append(f"{path}: empty; no run metadata")
        return {}
    if not isinstance(doc, dict):
        raise ConfigError(str(path), "", "run metadata must be a mapping")
    return doc


def _complete_length(f: IO[bytes]) -> tuple[int, int]:
    """(bytes up to and including the last newline, file size). Trailing NUL bytes (a tail the
    file system extended but never wrote) count as part of the incomplete tail."""
    size = f.seek(0, 2)
    end = size
    while end > 0:
        start = max(0, end - _TAIL_BLOCK)
        f.seek(start)
        block = f.read(end - start)
        nl = block.rfind(b"\n")
        if nl >= 0:
            return start + nl + 1, size
        end = start
    return 0, size


def _lines(f: IO[bytes], limit: int, path: Path) -> Iterator[str]:
    f.seek(0)
    pos = 0
    for n, raw in enumerate(f, start=1):
        pos += len(raw)
        if pos > limit:
            return
        try:
            yield raw.decode("utf-8")
        except UnicodeDecodeError as exc:
            raise ConfigError(str(path), f"line {n}", "not UTF-8 text") from exc


def _load_samples(path: Path, warnings: list[str]) -> tuple[list[str], dict[str, np.ndarray], int]:
    try:
        f = open(path, "rb")  # noqa: SIM115 - closed below
    except OSError as exc:
        raise ConfigError(str(path), "", f"cannot open run samples: {exc.strerror or exc}") from exc
    with f:
        limit, size = _complete_length(f)
        tail = size - limit
        reader = csv.reader(_lines(f, limit, path), strict=True)
        try:
            header = next(reader, None)
        except csv.Error as exc:
            raise ConfigError(str(path), "line 1", f"bad CSV header: {exc}") from exc
        if header is None:
            if size:
                raise ConfigError(str(path), "line 1", "header line is incomplete")
            raise ConfigError(str(path), "", "empty file: no header line")
        columns = [c.strip() for c in header]
        _check_header(path, columns)
        text_cols = [j for j, c in enumerate(columns) if c in TEXT_COLUMNS]
        chunks: list[list[np.ndarray]] = [[] for _ in columns]
        rows: list[list[str]] = []
        line_nos: list[int] = []
        width = len(columns)
        try:
            for row in reader:
                if len(row) != width:
                    if row == [] or row == [""]:
                        continue  # a blank line
                    raise ConfigError(
                        str(path),
                        f"line {reader.line_num}",
                        f"{len(row)} fields for {width} columns",
                    )
                rows.append(row)
                line_nos.append(reader.line_num)
                if len(rows) >= CHUNK_ROWS:
                    _convert(path, columns, text_cols, rows, line_nos, chunks)
                    rows, line_nos = [], []
        except csv.Error as exc:
            raise ConfigError(str(path), f"line {reader.line_num}", f"bad CSV: {exc}") from exc
        if rows:
            _convert(path, columns, text_cols, rows, line_nos, chunks)
    if tail:
        warnings.append(
            f"{path}: dropped an incomplete last line ({tail} bytes; the writer was stopped"
            " mid-write)"
        )
    data: dict[str, np.ndarray] = {}
    for j, name in enumerate(columns):
        parts = chunks[j]
        if not parts:
            data[name] = np.array([], dtype=object if j in text_cols else float)
        elif any(p.dtype == object for p in parts):
            data[name] = np.concatenate([p.astype(object) for p in parts])
        else:
            data[name] = np.concatenate(parts)
    return columns, data, tail


def _check_header(path: Path, columns: list[str]) -> None:
    seen: set[str] = set()
    for j, name in enumerate(columns, start=1):
        if not name:
            raise ConfigError(str(path), "line 1", f"column {j} has no name")
        if name in seen:
            raise ConfigError(str(path), "line 1", f"column {name!r} appears twice")
        seen.add(name)
    if TIME not in seen:
        raise ConfigError(str(path), "line 1", f"no {TIME!r} column")


def _convert(
    path: Path,
    columns: list[str],
    text_cols: list[int],
    rows: list[list[str]],
    line_nos: list[int],
    chunks: list[list[np.ndarray]],
) -> None:
    """Convert one chunk of text rows (ending on lines ``line_nos``) to arrays; numeric
    columns strictly, extra columns as text if any field is not a number."""
    cols = list(zip(*rows, strict=True))
    for j, name in enumerate(columns):
        if j in text_cols:
            chunks[j].append(np.array(cols[j], dtype=object))
            continue
        col = cols[j]
        try:
            values = np.fromiter([float(v) if v else nan for v in col], float, len(col))
        except ValueError:
            parsed = [_parse(v) for v in col]
            bad = next((i for i, v in enumerate(parsed) if v is None), None)
            if bad is None:  # only fields of blanks
                values = np.array(parsed, dtype=float)
            elif group_of(name) is None and name != TIME:
                chunks[j].append(np.array(col, dtype=object))  # an extra text column
                continue
            else:
                raise ConfigError(
                    str(path),
                    f"line {line_nos[bad]}",
                    f"column {name!r} is not a number",
                    col[bad],
                ) from None
        chunks[j].append(values)
    t = chunks[columns.index(TIME)][-1]
    bad_t = np.flatnonzero(~np.isfinite(t))
    if bad_t.size:
        i = int(bad_t[0])
        raise ConfigError(str(path), f"line {line_nos[i]}", f"{TIME!r} is empty or not finite")


def _parse(text: str) -> float | None:
    """A field as a float: NaN when blank, None when not a number."""
    text = text.strip()
    if not text:
        return nan
    try:
        return float(text)
    except ValueError:
        return None
