"""Benchmark (not a test): the run log's cost on the loop's process, per row and per CAN frame.

Run: ``.venv/bin/python benchmarks/bench_runlog_write.py [--rows 100000] [--frames 64000]``.

Prints, in one thread with nothing else running in the process (``time.perf_counter_ns``
around each call, median and mean; the calls alternate between the variants in rounds, so a
load that comes and goes hits them alike):

1. the loop's row hand-over: ``deque.append`` of the loop's ``CycleRow`` (the thread writer's
   ``write`` before the writer process), and ``ProcessRunLogWriter.write`` of the same row (its
   numbers into the shared ring: one ``struct`` store and one memoryview copy);
2. the CAN frames into the ring for ``run.mcap``'s ``/can``: ``RingCanTap`` called per frame
   (``on_message_received``) and per batch of ``TAP_BATCH_FRAMES`` frames (``on_messages``, as
   the traffic log's thread hands them over), per frame.

Numbers depend on the machine and its load, and a warm cache: inside the 1 kHz loop, which
sleeps between cycles, the same calls cost several times more (``benchmarks/bench_loop.py
--runlog``, ``benchmarks/bench_runlog_loop.py``). They are measurements, not claims checked by
tests.
"""

from __future__ import annotations

import argparse
import collections
import tempfile
import time
from pathlib import Path

import can
import numpy as np

from cdcr_ctl.control.loop.rows import CycleRow, RowLayout
from cdcr_ctl.drives.group.traffic import TAP_BATCH_FRAMES
from cdcr_ctl.runlog.columns import LOOP_EXTRA_COLUMNS, sample_columns
from cdcr_ctl.runlog.writer import RunMetadata
from cdcr_ctl.runlog.writer.process import ProcessRunLogWriter
from cdcr_ctl.runlog.writer.ring import RingLayout, SharedRing
from cdcr_ctl.runlog.writer.spawn import RingCanTap

#: Calls per round of each variant.
ROUND = 1000


def rows_cost(n_rows: int) -> dict[str, np.ndarray]:
    """ns per row hand-over: deque.append and ProcessRunLogWriter.write of the loop's row."""
    S, K = 1, 3
    layout = RowLayout(S, K)
    rng = np.random.default_rng(0)
    rows = [
        CycleRow(layout, i * 1e-3, i, rng.normal(size=2 * S + 4 * K + 3), 3.3e-6 * i, "")
        for i in range(n_rows)
    ]
    work = Path(tempfile.mkdtemp(prefix="bench_runlog_write_"))
    cols = sample_columns(S, K, LOOP_EXTRA_COLUMNS)
    writer = ProcessRunLogWriter(
        work / "run", cols, RunMetadata(name="bench"), max_queued_rows=n_rows + 1
    )
    queue: collections.deque = collections.deque()
    calls = {"deque.append": queue.append, "ProcessRunLogWriter.write": writer.write}
    cost = {k: np.empty(n_rows) for k in calls}
    clock = time.perf_counter_ns
    for start in range(0, n_rows, ROUND):
        for name, call in calls.items():
            out = cost[name]
            for i in range(start, min(start + ROUND, n_rows)):
                a = clock()
                call(rows[i])
                out[i] = clock() - a
    writer.close("benchmark done")
    assert writer.stats.written == n_rows, writer.stats
    return cost


def frames_cost(n_frames: int) -> dict[str, np.ndarray]:
    """ns per frame into the ring: RingCanTap per frame and per batch."""
    msgs = [
        can.Message(timestamp=1000.0 + i * 1e-4, arbitration_id=0x181 + i % 3,
                    data=bytes([i % 256, 0x16, 0, 0, 0, 0]), is_extended_id=False, is_rx=True)
        for i in range(n_frames)
    ]  # fmt: skip
    cost: dict[str, list[float]] = {"per frame": [], f"batches of {TAP_BATCH_FRAMES}": []}
    rings = [SharedRing.create(RingLayout(1, 1, n_frames)) for _ in cost]
    taps = [RingCanTap(r) for r in rings]
    clock = time.perf_counter_ns
    batch = TAP_BATCH_FRAMES
    for start in range(0, n_frames, batch * 16):
        chunk = msgs[start : start + batch * 16]
        one = taps[0].on_message_received
        for m in chunk:
            a = clock()
            one(m)
            cost["per frame"].append(clock() - a)
        for i in range(0, len(chunk), batch):
            part = chunk[i : i + batch]
            a = clock()
            taps[1].on_messages(part)
            cost[f"batches of {batch}"].append((clock() - a) / len(part))
    for ring, tap in zip(rings, taps, strict=True):
        assert len(ring.take_frames()) == n_frames and tap.dropped == 0
        ring.close()
    return {k: np.array(v) for k, v in cost.items()}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--rows", type=int, default=100_000)
    ap.add_argument("--frames", type=int, default=64_000)
    args = ap.parse_args()
    print(f"row hand-over, {args.rows} rows of the Qi rig (1 segment, 3 cables), ns per row:")
    for name, c in rows_cost(args.rows).items():
        print(f"  {name}: median {np.median(c):.0f}, mean {c.mean():.0f}")
    print(f"CAN frames into the ring, {args.frames} frames, ns per frame:")
    for name, c in frames_cost(args.frames).items():
        print(f"  RingCanTap {name}: median {np.median(c):.0f}, mean {c.mean():.0f}")


if __name__ == "__main__":
    main()
