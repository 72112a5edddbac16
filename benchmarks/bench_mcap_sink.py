"""Benchmark (not a test): the MCAP sink's CPU time per row, with and without message indexes.

Run: ``.venv/bin/python benchmarks/bench_mcap_sink.py [--rows 20000] [--rounds 5]``.

Prints, in one thread with nothing else running in the process (``time.process_time`` around
each variant; the variants alternate in rounds, so a load that comes and goes hits them alike;
median and every round):

1. :class:`~cdcr_ctl.runlog.mcap_sink.McapSink` writing ``--rows`` rows of a 2-segment,
   3-cable rig (batches of 50 rows, as the writer thread drains them, a flush every 500 rows,
   as ``fsync_every_s`` 0.5 s at 1 kHz does) to a file: without message indexes, and with them
   as the sink writes them;
2. one message index record of 1000 entries, written by the ``mcap`` library's
   ``MessageIndex.write`` and by :class:`~cdcr_ctl.runlog.mcap_chunk.PackedMessageIndex` (the
   same bytes, checked), per message (best of 5 repeats of 200 writes).

Numbers depend on the machine and its load; they are measurements, not claims checked by tests.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
import timeit
from pathlib import Path

import numpy as np
from mcap.data_stream import RecordBuilder
from mcap.records import MessageIndex
from mcap.writer import IndexType

from cdcr_ctl.runlog.columns import LOOP_EXTRA_COLUMNS, sample_columns
from cdcr_ctl.runlog.mcap_chunk import PackedMessageIndex
from cdcr_ctl.runlog.mcap_sink import INDEXES, McapSink

BATCH_ROWS = 50
FLUSH_EVERY_ROWS = 500


def sink_cost(n_rows: int, rounds: int) -> dict[str, list[float]]:
    """us of CPU per row of McapSink.write_rows (and its flushes), per variant and round."""
    cols = sample_columns(2, 3, LOOP_EXTRA_COLUMNS)
    rng = np.random.default_rng(0)
    rows = [
        {c: float(rng.normal()) for c in cols} | {"t_s": i * 1e-3, "cycle": i, "event": ""}
        for i in range(n_rows)
    ]
    work = Path(tempfile.mkdtemp(prefix="bench_mcap_sink_"))
    variants = {
        "no message indexes": INDEXES & ~IndexType.MESSAGE,
        "message indexes (the sink)": INDEXES,
    }
    out: dict[str, list[float]] = {k: [] for k in variants}
    for r in range(rounds):
        for k, index_types in variants.items():
            path = work / f"{r}-{len(out[k])}-{index_types.value}.mcap"
            sink = McapSink(path, cols, index_types=index_types)
            sink.yield_every = 0
            t = time.process_time()
            for i in range(0, n_rows, BATCH_ROWS):
                sink.write_rows(rows[i : i + BATCH_ROWS])
                if (i + BATCH_ROWS) % FLUSH_EVERY_ROWS == 0:
                    sink.flush()
            sink.close()
            out[k].append(1e6 * (time.process_time() - t) / n_rows)
            path.unlink()
    return out


def index_cost() -> dict[str, float]:
    """ns per message of one 1000-entry message index record, library vs packed."""
    recs = [(1_700_000_000_000_000_000 + i * 1_000_000, i * 120) for i in range(1000)]
    out = {}
    written = []
    for cls in (MessageIndex, PackedMessageIndex):
        index = cls(channel_id=3, records=recs)

        def write(index: MessageIndex = index) -> bytes:
            b = RecordBuilder()
            index.write(b)
            return b.end()

        written.append(write())
        best = min(timeit.repeat(write, number=200, repeat=5))
        out[cls.__name__] = 1e9 * best / 200 / len(recs)
    assert written[0] == written[1], "the packed record differs from the library's"
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rows", type=int, default=20_000)
    ap.add_argument("--rounds", type=int, default=5)
    args = ap.parse_args()
    print(
        f"McapSink.write_rows, {args.rows} rows (S=2, K=3) in batches of {BATCH_ROWS},"
        f" a flush every {FLUSH_EVERY_ROWS} rows; process CPU per row, {args.rounds} rounds:"
    )
    for k, v in sink_cost(args.rows, args.rounds).items():
        rounds = ", ".join(f"{x:.1f}" for x in v)
        print(f"  {k}: median {statistics.median(v):.1f} us (rounds {rounds})")
    print("one message index record of 1000 entries, per message (best of 5 x 200 writes):")
    for k, ns in index_cost().items():
        print(f"  {k}.write: {ns:.0f} ns")


if __name__ == "__main__":
    main()
