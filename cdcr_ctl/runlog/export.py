"""Exports of a run log: CSV (a run directory any version of the reader opens), Parquet for batch
analysis, and the raw CAN traffic as a candump ``.log`` that ``canplayer`` and python-can's
player (``python -m can.player``) replay.

The source is whatever :func:`~cdcr_ctl.runlog.reader.load_run` reads (``samples.csv`` or
``run.mcap``). Floats are written as their shortest exact text (``repr``), so a CSV export reads
back to the same float64 values bit for bit (IEEE 754 round trip of ``repr``).
"""

from __future__ import annotations

import csv
import math
import shutil
from pathlib import Path
from typing import Any

import can
import pyarrow as pa
import pyarrow.parquet as pq
import yaml

from cdcr_ctl.errors import RigError
from cdcr_ctl.runlog.mcap_reader import read_mcap
from cdcr_ctl.runlog.mcap_sink import RUN_MCAP
from cdcr_ctl.runlog.reader import Run
from cdcr_ctl.runlog.writer import (
    CAN_LOG_NAMES,
    CONFIG_YAML,
    EFFECTIVE_CONFIG_YAML,
    RUN_YAML,
    SAMPLES_CSV,
)

PARQUET = "samples.parquet"
CANDUMP_LOG = "can.log"
#: Channel name written into candump lines (canplayer maps it with ``vcan0=can0`` style args).
CANDUMP_CHANNEL = "can0"
_INT_COLUMNS = frozenset({"cycle"})


def _text(name: str, v: Any) -> str:
    if isinstance(v, str):
        return v
    f = float(v)
    if math.isnan(f):
        return ""
    if name in _INT_COLUMNS and f.is_integer():
        return str(int(f))
    return repr(f)


def export_csv(run: Run, out_dir: str | Path) -> Path:
    """Write ``run`` as a run directory: ``samples.csv``, ``run.yaml`` and the config copies.
    Returns the directory. Raises :class:`RigError` naming the path on a write error."""
    out = Path(out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
        cols = run.columns
        arrays = [run.data[c] for c in cols]
        with open(out / SAMPLES_CSV, "w", encoding="utf-8", newline="") as f:
            w = csv.writer(f, lineterminator="\n")
            w.writerow(cols)
            for i in range(len(run)):
                w.writerow([_text(c, a[i]) for c, a in zip(cols, arrays, strict=True)])
        (out / RUN_YAML).write_text(
            yaml.safe_dump(run.metadata, sort_keys=False, allow_unicode=True), encoding="utf-8"
        )
        _copy_configs(run, out)
    except OSError as exc:
        raise RigError(f"{out}: cannot write the CSV export: {exc.strerror or exc}") from exc
    return out


def _copy_configs(run: Run, out: Path) -> None:
    """Config copies beside the source, else from the MCAP file's attachments."""
    attachments: dict[str, bytes] = {}
    mcap = run.run_dir / RUN_MCAP
    for name in (CONFIG_YAML, EFFECTIVE_CONFIG_YAML):
        src = run.run_dir / name
        if src.is_file() and src.resolve() != (out / name).resolve():
            shutil.copyfile(src, out / name)
        elif not src.is_file() and mcap.is_file():
            if not attachments:
                attachments = read_mcap(mcap).attachments
            if name in attachments:
                (out / name).write_bytes(attachments[name])


def export_parquet(run: Run, path: str | Path) -> Path:
    """Write the columns of ``run`` as one Parquet table (zstd), column names as in the CSV,
    the run's metadata as the table's ``cdcr_run`` key (YAML)."""
    p = Path(path)
    table = pa.table(
        {c: (run.data[c].astype(str) if run.data[c].dtype == object else run.data[c])
         for c in run.columns}
    )  # fmt: skip
    meta = {b"cdcr_run": yaml.safe_dump(run.metadata, sort_keys=False).encode()}
    table = table.replace_schema_metadata({**(table.schema.metadata or {}), **meta})
    try:
        p.parent.mkdir(parents=True, exist_ok=True)
        pq.write_table(table, p, compression="zstd")
    except OSError as exc:
        raise RigError(f"{p}: cannot write the Parquet export: {exc.strerror or exc}") from exc
    return p


def can_messages(run: Run) -> list[can.Message]:
    """The run's raw CAN frames: the ``/can`` channel of ``run.mcap``, else the python-can
    ASC/BLF file beside it. Empty when the run has neither."""
    mcap = run.run_dir / RUN_MCAP
    if mcap.is_file():
        frames = read_mcap(mcap, with_can=True).can_frames
        if frames:
            return [
                can.Message(
                    timestamp=fr["timestamp_s"],
                    arbitration_id=fr["id"],
                    is_extended_id=fr["extended"],
                    is_rx=fr["rx"],
                    is_error_frame=fr["error"],
                    is_remote_frame=fr["remote"],
                    dlc=fr["dlc"],
                    data=bytes.fromhex(fr["data"]),
                    channel=CANDUMP_CHANNEL,
                )
                for fr in frames
            ]
    for name in CAN_LOG_NAMES:
        src = run.run_dir / name
        if src.is_file():
            out = []
            for m in can.LogReader(str(src)):
                m.channel = CANDUMP_CHANNEL
                out.append(m)
            return out
    return []


def export_candump(messages: list[can.Message], path: str | Path) -> Path:
    """Write frames as a candump ``-L`` log (python-can's ``CanutilsLogWriter``)."""
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    writer = can.Logger(str(p))
    try:
        for m in messages:
            writer.on_message_received(m)
    finally:
        writer.stop()
    return p


__all__ = [
    "CANDUMP_LOG",
    "PARQUET",
    "can_messages",
    "export_candump",
    "export_csv",
    "export_parquet",
]
