"""``run.mcap``: the run log as MCAP, written beside ``samples.csv`` by the run-log writer thread.

One file per run. Channels and schemas are those of :mod:`cdcr_ctl.runlog.streams`. The rig
config as loaded (``config.yaml``) and as validated (``config_effective.yaml``) go in as
attachments at the start; ``run.yaml`` goes in as an attachment and as metadata ``run`` when the
run closes (a run killed before that has the start metadata ``run_start`` only).

Durability: the ``mcap`` writer keeps the current chunk in memory. :meth:`McapSink.flush`
closes it (zstd-compressed) and writes it to the file, its message indexes right after it; the
run-log writer calls it every ``fsync_every_s`` right before its fsync, so a process killed by
SIGKILL leaves a file whose complete chunks hold everything up to the last flush (a cut inside
the message indexes after a chunk keeps the chunk). Such a file has no
summary or footer; :mod:`cdcr_ctl.runlog.mcap_reader` reads it with the ``mcap`` package's
streaming reader and stops at the cut.

Nothing here runs on the real-time thread: rows reach :meth:`McapSink.write_rows` from the
writer thread's drain, CAN frames reach :class:`CanTap` as a deque append from whatever thread
sent or received them and are written at the next drain.

Imports: no numpy and no python-can (the run-log writer process, which makes the sink, starts
without them: ~0.1 s of CPU each). :class:`CanTap` is a python-can listener by its protocol
(``on_message_received``, called as ``listener(msg)``, ``stop``), which python-can's ``Notifier``
and the project's traffic log take; the ``/tip/model`` message comes with the ``model_tip`` the
caller gives (:class:`cdcr_ctl.runlog.model_tip.ModelTip`, numpy), when there is a model.
"""

from __future__ import annotations

import collections
import contextlib
import os
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from pathlib import Path
from typing import IO, Any

import yaml
from mcap.writer import CompressionType, IndexType, Writer

from cdcr_ctl import __version__
from cdcr_ctl.runlog import streams
from cdcr_ctl.runlog.mcap_chunk import MessageAppender
from cdcr_ctl.runlog.streams import RowStreams

#: ``model_tip(d, cycle, S)``: the ``/tip/model`` message of row ``d`` (a mapping of the
#: columns), or None (see :class:`cdcr_ctl.runlog.model_tip.ModelTip`).
ModelTipSource = Callable[[Mapping[str, Any], int, int], "dict[str, Any] | None"]

RUN_MCAP = "run.mcap"
RUN_YAML = "run.yaml"  # the writer's name for it (the writer imports this module, not back)
PROFILE = ""  # no ROS profile: JSON messages with JSON Schemas
LIBRARY = f"cdcr-ctl {__version__}"
#: Chunk size at which the mcap writer closes a chunk by itself (bytes, uncompressed).
#: Small enough that compressing one (a few ms for 256 KiB here) never holds the writer thread
#: long; the chunk is closed at each flush (``fsync_every_s``) in any case.
CHUNK_BYTES = 256 * 1024
#: Indexes written: all of them. The message indexes (16 bytes per message, outside the
#: compressed chunks) follow each chunk in the same flush; the official TypeScript reader
#: (``McapIndexedReader`` of ``@mcap/core``, the Foxglove app's reader of seekable files) refuses
#: a chunk index without them. Their size: ``benchmarks/bench_runlog_size.py``.
INDEXES = IndexType.ALL
#: Rows encoded between two voluntary releases of the GIL (the loop thread never waits long).
YIELD_EVERY_ROWS = 4
#: Bound of the CAN frame queue (frames); beyond it frames are counted as dropped.
CAN_QUEUE_FRAMES = 200_000


class CanTap:
    """A python-can listener (by protocol, see the module docstring) that queues frames for
    ``/can``; cheap on the caller's thread."""

    def __init__(self, max_frames: int = CAN_QUEUE_FRAMES) -> None:
        self.queue: collections.deque[tuple] = collections.deque()
        self.max_frames = max_frames
        self.dropped = 0

    def on_message_received(self, msg: Any) -> None:
        """One ``can.Message``, queued as a tuple (dropped and counted beyond the bound)."""
        if len(self.queue) >= self.max_frames:
            self.dropped += 1
            return
        self.queue.append(
            (
                msg.timestamp,
                msg.arbitration_id,
                msg.is_extended_id,
                msg.is_rx,
                msg.is_error_frame,
                msg.is_remote_frame,
                msg.dlc,
                bytes(msg.data),
            )
        )

    __call__ = on_message_received  # python-can calls a listener with the message

    def stop(self) -> None:  # python-can API; nothing to release
        pass


class McapSink:
    """Writes one ``run.mcap``. Not thread-safe: one thread (the run-log writer's) calls it.

    ``attachments``: file name -> text (the configs). ``start_metadata``: string map stored as
    metadata ``run_start``. ``model_tip`` (optional): the ``/tip/model`` message of a row (see
    :class:`cdcr_ctl.runlog.model_tip.ModelTip`), written every ``model_tip_every`` cycles.
    Raises OSError if the file cannot be created.
    """

    def __init__(
        self,
        path: str | Path,
        columns: Sequence[str],
        *,
        attachments: Mapping[str, str] | None = None,
        start_metadata: Mapping[str, str] | None = None,
        model_tip: ModelTipSource | None = None,
        model_tip_every: int = 1,
        opener: Callable[[Path], IO[bytes]] | None = None,
        index_types: IndexType = INDEXES,
    ) -> None:
        self.path = Path(path)
        self.rows = RowStreams(tuple(columns))
        self.model_tip = model_tip
        self.model_tip_every = max(1, int(model_tip_every))
        self.can_tap = CanTap()
        self.messages = 0
        self.rows_written = 0
        #: Rows encoded between two releases of the GIL (0: never; the run-log writer process
        #: has no real-time thread to give it to).
        self.yield_every = YIELD_EVERY_ROWS
        #: UNIX time (ns) of loop time 0: the wall clock when the first row is written minus
        #: its ``t_s`` (None before it).
        self._epoch_ns: int | None = None
        #: ``t_s``, ``cycle`` and log time (ns) of the last row written (None, -1, 0 before it).
        self._last_row: tuple[float | None, int, int] = (None, -1, 0)
        self._file = opener(self.path) if opener else open(self.path, "xb")  # noqa: SIM115
        self._w = Writer(
            self._file,
            chunk_size=CHUNK_BYTES,
            compression=CompressionType.ZSTD,
            index_types=index_types,
        )
        self._w.start(profile=PROFILE, library=LIBRARY)
        now = time.time_ns()
        for name, text in (attachments or {}).items():
            self._w.add_attachment(now, now, name, "application/yaml", text.encode("utf-8"))
        if start_metadata:
            self._w.add_metadata("run_start", {k: str(v) for k, v in start_metadata.items()})
        self._channels: dict[str, int] = {}
        for topic, (name, _) in streams.SCHEMAS.items():
            sid = self._w.register_schema(name, "jsonschema", streams.schema_bytes(topic))
            self._channels[topic] = self._w.register_channel(topic, "json", sid)
        self._seq: collections.Counter[str] = collections.Counter()
        #: ``Writer.add_message``, a record in one store (:mod:`cdcr_ctl.runlog.mcap_chunk`).
        self._append = MessageAppender(self._w)
        self.flush()

    # ------------------------------------------------------------------ writing
    def _add(self, topic: str, log_time_ns: int, msg: Mapping[str, Any] | bytes) -> None:
        seq = self._seq[topic] + 1
        self._seq[topic] = seq
        data = msg if isinstance(msg, bytes) else streams.encode(msg)
        self._append(self._channels[topic], log_time_ns, data, log_time_ns, seq)
        self.messages += 1

    def write_rows(self, rows: Iterable[Mapping[str, Any] | Sequence[Any]]) -> None:
        """Encode and add the messages of ``rows`` (run-log rows in column order or mappings).

        ``log_time`` is UNIX time (ns): the wall clock at the first row minus its ``t_s``, plus
        each row's ``t_s``, so Foxglove shows wall-clock times and the spacing of the loop."""
        S = self.rows.counts[0]
        for n, row in enumerate(rows, start=1):
            d = self.rows.as_dict(row)
            t = d.get("t_s")
            t = float(t) if t is not None else 0.0
            if self._epoch_ns is None:
                self._epoch_ns = time.time_ns() - round(t * 1e9)
            log_ns = self._epoch_ns + round(t * 1e9)
            index = self.rows_written
            cyc = d.get("cycle")
            cyc = int(cyc) if cyc is not None and cyc == cyc else index
            self._last_row = (t, cyc, log_ns)
            for topic, msg in self.rows.encoded(d, index):
                self._add(topic, log_ns, msg)
            if self.model_tip is not None and S and index % self.model_tip_every == 0:
                cyc = d.get("cycle")
                tip = self.model_tip(d, int(cyc) if cyc is not None else index, S)
                if tip is not None:
                    self._add(streams.TIP_MODEL, log_ns, tip)
            self.rows_written += 1
            if self.yield_every and n % self.yield_every == 0:
                time.sleep(0)
        self.write_can()

    def write_can(self, final: bool = False) -> None:
        """Add the CAN frames queued by :attr:`can_tap` so far.

        A frame's ``t_s`` and ``cycle`` are those of the last row written before it (frames
        and rows reach the writer in batches, so the frame's own cycle may be earlier or the
        next); its own time (UNIX s) is ``timestamp_s``, which is also its log time; a frame
        the bus did not stamp (python-can's 0.0, as a lock-step bus leaves received frames) is
        logged at that row's log time. Frames wait in the queue until a row is written
        (``final``: at close, a run without rows writes them with ``t_s`` null and ``cycle``
        -1)."""
        q = self.can_tap.queue
        if self._epoch_ns is None and not final:
            return
        t_s, cycle, row_ns = self._last_row
        while q:
            ts, cob, ext, rx, err, rtr, dlc, data = q.popleft()
            msg = {
                "t_s": t_s,
                "cycle": cycle,
                "timestamp_s": ts,
                "id": cob,
                "extended": ext,
                "rx": rx,
                "error": err,
                "remote": rtr,
                "dlc": dlc,
                "data": data.hex(),
            }
            self._add(streams.CAN, round(ts * 1e9) if ts else row_ns, msg)

    def flush(self) -> None:
        """Close the chunk in progress and hand everything to the OS (no fsync)."""
        self._w.flush()

    def fileno(self) -> int:
        return self._file.fileno()

    def close(self, run_yaml: str | None = None, ok: bool = True) -> None:
        """Write the last chunk, ``run.yaml`` (attachment, and metadata ``run``: its top-level
        keys, values as YAML), the summary and the footer; close the file. ``ok`` False (the
        run log failed) still tries, and never raises past an OSError of the file."""
        try:
            self.write_can(final=True)
            if run_yaml is not None:
                now = time.time_ns()
                self._w.add_attachment(now, now, "run.yaml", "application/yaml", run_yaml.encode())
                self._w.add_metadata("run", yaml_metadata(run_yaml))
            self._w.finish()
            self._file.flush()
            with contextlib.suppress(OSError, ValueError, AttributeError):  # not a real file
                os.fsync(self._file.fileno())
        finally:
            self._file.close()


def yaml_metadata(text: str) -> dict[str, str]:
    """A YAML mapping as MCAP metadata (string -> string): each top-level value as YAML text, a
    scalar as its plain text (``250.0``, ``true``; no document end marker), a collection in flow
    style (``{rows: 6001, ...}``); ``yaml.safe_load`` of a value gives the value back."""
    try:
        doc = yaml.safe_load(text)
    except yaml.YAMLError:
        return {"yaml": text}
    if not isinstance(doc, dict):
        return {"yaml": text}
    return {str(k): v if isinstance(v, str) else _yaml_text(v) for k, v in doc.items()}


def _yaml_text(value: Any) -> str:
    text = yaml.safe_dump(value, default_flow_style=True, width=1 << 30)
    if text.endswith("\n...\n"):  # a plain scalar at the top ends its document explicitly
        text = text[: -len("...\n")]
    return text.strip()


class McapSinkFactory:
    """The run-log writer's ``second_sink``: a :class:`McapSink` at ``<run_dir>/run.mcap`` with
    the config copies as attachments and the starting ``run.yaml`` as metadata ``run_start``;
    ``model_tip`` (:class:`~cdcr_ctl.runlog.model_tip.ModelTip`) for ``/tip/model``, written at
    most every :func:`~cdcr_ctl.runlog.streams.model_tip_every` cycles of ``rate_hz``."""

    def __init__(
        self,
        model_tip: ModelTipSource | None = None,
        rate_hz: float | None = None,
        index_types: IndexType = INDEXES,
    ) -> None:
        self.model_tip = model_tip
        self.model_tip_every = streams.model_tip_every(rate_hz)
        self.index_types = index_types

    def __call__(self, run_dir: Path, columns: list[str], files: dict[str, str]) -> McapSink:
        start = run_dir / RUN_YAML
        meta = yaml_metadata(start.read_text(encoding="utf-8")) if start.is_file() else None
        return McapSink(
            run_dir / RUN_MCAP,
            columns,
            attachments=files,
            start_metadata=meta,
            model_tip=self.model_tip,
            model_tip_every=self.model_tip_every,
            index_types=self.index_types,
        )
