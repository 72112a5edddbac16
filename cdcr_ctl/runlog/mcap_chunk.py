"""Messages into an ``mcap`` writer's chunk, a record in one ``struct`` store.

``mcap.writer.Writer.add_message`` makes a ``Message`` dataclass per message and writes its
record field by field (a ``struct.pack`` and a ``BytesIO`` write each, then a seek back for the
length): ~6 us a message here, five messages a logged row, a third of the run-log writer
process's CPU per row. :class:`MessageAppender` does what it does, in the same order and to the
same state (the file's statistics, the chunk's start and end times, its message index, the
record bytes, the chunk closed when it exceeds its size) with one ``struct`` store of the
record's head and one write of the payload; its message indexes (:class:`PackedMessageIndex`)
are written with one ``struct`` store each instead of two per message (72 against 412 ns a
message, ``benchmarks/bench_mcap_sink.py``). It reaches the writer's chunk builder and
statistics through their (name-mangled) attributes: a writer without them (another ``mcap``
version) gets ``add_message`` itself. ``tests/runlog/test_mcap_chunk.py`` holds the two paths'
files equal byte for byte.
"""

from __future__ import annotations

import struct
from itertools import chain
from typing import Any

from mcap.data_stream import RecordBuilder
from mcap.opcode import Opcode
from mcap.records import MessageIndex
from mcap.writer import Writer

#: A message record's head: opcode, record length (after these 9 bytes), channel id, sequence,
#: log time, publish time (ns); the payload follows.
MESSAGE_HEAD = struct.Struct("<BQHIQQ")
#: The record length of a message without its payload.
_FIXED = MESSAGE_HEAD.size - 9


class PackedMessageIndex(MessageIndex):
    """``MessageIndex`` whose record is written with one ``struct`` store of all its (log time,
    offset) pairs: the same bytes as the library's ``write`` (uint16 channel id, uint32 byte
    length of the pairs, uint64 pairs, little-endian), without a call per value."""

    def write(self, stream: RecordBuilder) -> None:
        n = len(self.records)
        stream.start_record(Opcode.MESSAGE_INDEX)
        pairs = chain.from_iterable(self.records)
        stream.write(struct.pack(f"<HI{2 * n}Q", self.channel_id, 16 * n, *pairs))
        stream.finish_record()


class MessageAppender:
    """Adds messages to ``writer`` (a chunked ``mcap.writer.Writer``): call as
    ``appender(channel_id, log_time, data, publish_time, sequence)``, the arguments of
    ``Writer.add_message``. :attr:`fast` False: the writer lacks the expected internals (or does
    not chunk) and ``add_message`` is called."""

    def __init__(self, writer: Writer) -> None:
        self._writer = writer
        try:
            chunk: Any = writer._Writer__chunk_builder  # type: ignore[attr-defined]
            self._stats: Any = writer._Writer__statistics  # type: ignore[attr-defined]
            self._maybe_close = writer._Writer__maybe_finalize_chunk  # type: ignore[attr-defined]
            self._chunk_size: int = writer._Writer__chunk_size  # type: ignore[attr-defined]
            fast = chunk is not None and all(
                hasattr(chunk, a)
                for a in ("record_writer", "message_indices", "num_messages", "message_end_time")
            )
            fast = fast and hasattr(chunk.record_writer, "_buffer")
            fast = fast and hasattr(self._stats, "channel_message_counts")
        except AttributeError:
            chunk, fast = None, False
        self._chunk = chunk
        self.fast = fast

    def __call__(
        self, channel_id: int, log_time: int, data: bytes, publish_time: int, sequence: int
    ) -> None:
        if not self.fast:
            self._writer.add_message(channel_id, log_time, data, publish_time, sequence)
            return
        stats = self._stats
        if stats.message_count == 0 or log_time < stats.message_start_time:
            stats.message_start_time = log_time
        if log_time > stats.message_end_time:
            stats.message_end_time = log_time
        stats.channel_message_counts[channel_id] += 1
        stats.message_count += 1
        chunk = self._chunk
        if chunk.num_messages == 0 or log_time < chunk.message_start_time:
            chunk.message_start_time = log_time
        if log_time > chunk.message_end_time:
            chunk.message_end_time = log_time
        buf = chunk.record_writer._buffer  # a new one after each chunk
        index = chunk.message_indices.get(channel_id)
        if index is None:
            index = chunk.message_indices[channel_id] = PackedMessageIndex(
                channel_id=channel_id, records=[]
            )
        index.records.append((log_time, buf.tell()))
        chunk.num_messages += 1
        buf.write(
            MESSAGE_HEAD.pack(
                Opcode.MESSAGE, _FIXED + len(data), channel_id, sequence, log_time, publish_time
            )
        )
        buf.write(data)
        if buf.tell() > self._chunk_size:  # the writer's own test, which it then repeats
            self._maybe_close()
