"""Read ``run.mcap`` back into the run log's columns (the same arrays ``samples.csv`` gives).

The file is read front to back with the ``mcap`` package's :class:`~mcap.stream_reader.StreamReader`
(records in file order, chunks decompressed and broken up by the library). A complete file ends
with its summary and footer. A file whose writer was killed (SIGKILL, power cut) ends inside a
record: the library raises at the cut (``EndOfFile``, or a length limit on zero-filled tails) and
everything before it, every complete chunk, i.e. every row up to the writer's last flush, is kept;
:attr:`McapRun.warnings` says where it stopped. The library's summary is not used for reading, so
complete and cut files go through one path.

Rows are joined by ``cycle`` across channels; the order of ``/command`` messages is the row order.
A row missing from another channel (it cannot happen in a file this project wrote, whose chunks
hold whole rows) reads as NaN there.
"""

from __future__ import annotations

import json
import struct
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from mcap.exceptions import McapError
from mcap.records import Attachment, Channel, Message, Metadata
from mcap.stream_reader import CRCValidationError, StreamReader
from zstandard import ZstdError

from cdcr_ctl.errors import ConfigError
from cdcr_ctl.runlog import streams
from cdcr_ctl.runlog.columns import (
    LOOP_EXTRA_COLUMNS,
    TEXT_COLUMNS,
    TIP_COLUMNS,
    cable_column,
    phi_cmd,
    sample_columns,
    theta_cmd,
)

#: What a cut file raises in the ``mcap`` library: the end inside a record (EndOfFile and other
#: McapErrors, struct.error inside a length field), a zero-filled tail read as a chunk (its
#: decompression or its CRC fails).
_CUT = (McapError, struct.error, ZstdError, CRCValidationError)


@dataclass
class McapRun:
    """What :func:`read_mcap` found: the columns as arrays (float64, NaN for null; ``event`` as
    text), the attachments (name -> bytes), the metadata records (name -> string map), the CAN
    frames (``/can`` messages as dicts) and warnings."""

    columns: list[str]
    data: dict[str, np.ndarray]
    attachments: dict[str, bytes] = field(default_factory=dict)
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)
    can_frames: list[dict[str, Any]] = field(default_factory=list)
    model_tip: list[dict[str, Any]] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    complete: bool = True

    def run_yaml(self) -> dict[str, Any] | None:
        """``run.yaml`` from the attachment written at close, else the start metadata."""
        text = self.attachments.get("run.yaml")
        if text is not None:
            doc = yaml.safe_load(text.decode("utf-8"))
            return doc if isinstance(doc, dict) else None
        start = self.metadata.get("run_start")
        if start is None:
            return None
        return {k: yaml.safe_load(v) for k, v in start.items()}


def read_mcap(path: str | Path, *, with_can: bool = False) -> McapRun:
    """Read a run's MCAP file. ``with_can``: also return the ``/can`` frames.

    Raises :class:`ConfigError` naming the file if it is not MCAP (bad magic, no header) or a
    message is not the JSON its channel says.
    """
    p = Path(path)
    channels: dict[int, str] = {}
    by_topic: dict[str, list[dict[str, Any]]] = {t: [] for t in streams.SCHEMAS}
    out = McapRun(columns=[], data={})
    n_records = 0
    try:
        f = open(p, "rb")  # noqa: SIM115 - closed below
    except OSError as exc:
        why = f"cannot open the MCAP run log: {exc.strerror or exc}"
        raise ConfigError(str(p), "", why) from exc
    with f:
        size = f.seek(0, 2)
        f.seek(0)
        reader = StreamReader(f, validate_crcs=True, record_size_limit=max(size, 1))
        try:
            for rec in reader.records:
                n_records += 1
                if isinstance(rec, Message):
                    topic = channels.get(rec.channel_id)
                    if topic is None:
                        raise ConfigError(str(p), f"message {n_records}", "unknown channel id")
                    if topic == streams.CAN and not with_can:
                        continue
                    try:
                        by_topic.setdefault(topic, []).append(json.loads(rec.data))
                    except ValueError as exc:
                        raise ConfigError(
                            str(p), f"topic {topic}", f"message is not JSON: {exc}"
                        ) from exc
                elif isinstance(rec, Channel):
                    channels[rec.id] = rec.topic
                elif isinstance(rec, Attachment):
                    out.attachments[rec.name] = rec.data
                elif isinstance(rec, Metadata):
                    out.metadata[rec.name] = dict(rec.metadata)
        except _CUT as exc:
            if n_records == 0:
                raise ConfigError(str(p), "", f"not an MCAP file: {exc}") from exc
            out.complete = False
            out.warnings.append(
                f"{p}: the file is cut or damaged at record {n_records + 1}"
                f" ({type(exc).__name__}: {exc}; the writer was stopped):"
                f" read {len(by_topic[streams.COMMAND])} rows up to the last flush"
            )
    _assemble(out, by_topic)
    if with_can:
        out.can_frames = by_topic.get(streams.CAN, [])
    out.model_tip = by_topic.get(streams.TIP_MODEL, [])
    return out


def _assemble(out: McapRun, by_topic: dict[str, list[dict[str, Any]]]) -> None:
    cmds = by_topic[streams.COMMAND]
    S = max((len(m.get("theta_rad") or ()) for m in cmds), default=0)
    K = max((len(m.get("q_cmd_mm") or ()) for m in cmds), default=0)
    extra_names: list[str] = []
    for m in by_topic.get(streams.EXTRA, ()):
        for name in m.get("values", {}):
            if name not in extra_names:
                extra_names.append(name)
    extras = [*LOOP_EXTRA_COLUMNS, *extra_names]
    out.columns = sample_columns(max(S, 1), max(K, 1), extras)
    n = len(cmds)
    index = {m["cycle"]: i for i, m in enumerate(cmds)}
    data: dict[str, np.ndarray] = {}

    def col(values: list[Any]) -> np.ndarray:
        return np.array([np.nan if v is None else v for v in values], dtype=float)

    def fill(topic: str, key: str, width: int | None, names: list[str]) -> None:
        arrs = [np.full(n, np.nan) for _ in names]
        for m in by_topic.get(topic, ()):
            i = index.get(m.get("cycle"))
            if i is None:
                continue
            v = m.get(key) if width is not None else [m.get(k) for k in key.split(",")]
            if v is None:
                continue
            for j, x in enumerate(v[: len(names)]):
                if x is not None:
                    arrs[j][i] = x
        data.update(zip(names, arrs, strict=True))

    data["t_s"] = col([m.get("t_s") for m in cmds])
    data["cycle"] = col([m.get("cycle") for m in cmds])
    rng_s, rng_k = range(1, S + 1), range(1, K + 1)
    cols = {
        "theta_rad": [theta_cmd(i) for i in rng_s],
        "phi_rad": [phi_cmd(i) for i in rng_s],
        "q_nominal_mm": [cable_column("q_nominal", k) for k in rng_k],
        "q_cmd_mm": [cable_column("q_cmd", k) for k in rng_k],
    }
    for key, names in cols.items():
        fill(streams.COMMAND, key, S, names)
    fill(streams.CABLES, "q_act_mm", K, [cable_column("q_act", k) for k in rng_k])
    fill(streams.TENSION, "tension_N", K, [cable_column("tension", k) for k in rng_k])
    fill(streams.TIP_TRACKED, "x_mm,y_mm,z_mm", None, list(TIP_COLUMNS))
    fill(streams.LOOP, "lateness_us", None, ["lateness_us"])
    events = np.array([""] * n, dtype=object)
    for m in by_topic.get(streams.EVENTS, ()):
        i = index.get(m.get("cycle"))
        if i is not None:
            events[i] = m.get("event", "")
    data["event"] = events
    for name in extra_names:
        arr = [None] * n
        for m in by_topic.get(streams.EXTRA, ()):
            i = index.get(m.get("cycle"))
            if i is not None:
                arr[i] = m.get("values", {}).get(name)
        try:
            data[name] = col(arr)
        except (TypeError, ValueError):
            data[name] = np.array(["" if v is None else str(v) for v in arr], dtype=object)
    for c in out.columns:  # columns of absent segments/cables (S or K was 0)
        if c not in data:
            data[c] = np.array([""] * n, dtype=object) if c in TEXT_COLUMNS else np.full(n, np.nan)
    out.data = data
