"""The MCAP sink's message fast path (cdcr_ctl/runlog/mcap_chunk.py) writes the same file, byte
for byte, as ``mcap.writer.Writer.add_message``: records, chunks closed at the same points,
chunk and message indexes (its :class:`~cdcr_ctl.runlog.mcap_chunk.PackedMessageIndex` records
as the library's), statistics."""

from __future__ import annotations

import io
import random

import pytest
from mcap.writer import CompressionType, IndexType, Writer

from cdcr_ctl.runlog.mcap_chunk import MessageAppender
from cdcr_ctl.runlog.mcap_sink import CHUNK_BYTES, INDEXES


def _file(fast: bool, index_types: IndexType, chunk_size: int, messages: list) -> bytes:
    out = io.BytesIO()
    w = Writer(
        out, chunk_size=chunk_size, compression=CompressionType.ZSTD, index_types=index_types
    )
    w.start(profile="", library="test")
    ids = []
    for topic in ("/a", "/b", "/c"):
        sid = w.register_schema(topic, "jsonschema", b"{}")
        ids.append(w.register_channel(topic, "json", sid))
    add = MessageAppender(w)
    assert add.fast  # the installed mcap has what the fast path needs
    for k, (ch, log_time, data, seq) in enumerate(messages):
        if fast:
            add(ids[ch], log_time, data, log_time, seq)
        else:
            w.add_message(
                ids[ch], log_time=log_time, data=data, publish_time=log_time, sequence=seq
            )
        if k == len(messages) // 2:
            w.flush()  # a chunk closed by the sink's flush (fsync_every_s) too
    w.finish()
    return out.getvalue()


@pytest.mark.parametrize("chunk_size", [CHUNK_BYTES, 700])
@pytest.mark.parametrize(
    "index_types",
    [INDEXES, IndexType.CHUNK | IndexType.ATTACHMENT | IndexType.METADATA],
    ids=["sink", "no-message-index"],
)
def test_fast_path_writes_the_same_file(chunk_size, index_types):
    rng = random.Random(7)
    t, messages = 1_700_000_000_000_000_000, []
    for seq in range(1, 600):
        t += rng.choice([0, 1, 4_000_000, -3])  # equal and out-of-order times too
        data = bytes(rng.randrange(256) for _ in range(rng.randrange(0, 90)))
        messages.append((rng.randrange(3), t, data, seq))
    assert _file(True, index_types, chunk_size, messages) == _file(
        False, index_types, chunk_size, messages
    )
