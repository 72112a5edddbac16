"""``run.mcap`` in the official TypeScript MCAP readers (``@mcap/core``'s ``McapIndexedReader``,
the Foxglove app's reader of seekable files, through ``@mcap/nodejs``; ``McapStreamReader`` with
CRC checks), run with Node from the lock in this directory (tests/interop/nodejs.py).

A run written by the run-log writer (``samples.csv`` and ``run.mcap`` from the same rows, CAN
frames into ``/can``, an extra column into ``/extra``, events, flushed every 50 ms so the file has
many chunks): both readers read every message, counts per channel equal to the rows logged and the
frames sent, every message JSON with ``t_s`` and ``cycle``. A file cut after a flush (a writer
killed) reads in the stream reader up to that flush. The demo runs' files are read in
tests/system/test_demo.py, the daemon's in tests/system/test_runlog_views.py.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import can
import numpy as np

from cdcr_ctl.runlog import RunLogWriter, RunMetadata, load_run, sample_columns, streams
from cdcr_ctl.runlog.columns import LOOP_EXTRA_COLUMNS
from cdcr_ctl.runlog.mcap_sink import RUN_MCAP, McapSink, McapSinkFactory
from cdcr_ctl.runlog.model_tip import ModelTip

sys.path.insert(0, str(Path(__file__).resolve().parent))
import nodejs  # tests/interop/nodejs.py: npm ci from the lock, node scripts

COLS = sample_columns(2, 3, (*LOOP_EXTRA_COLUMNS, "motor_temp_C"))
ROWS = 1500
FRAMES_PER_ROW = 2
RATE_HZ = 1000.0


def _row(i: int, rng: np.random.Generator) -> dict:
    d = {c: float(rng.normal()) for c in COLS}
    d.update(t_s=i / RATE_HZ, cycle=i, lateness_us=float(rng.uniform(0, 50)))
    d["event"] = "tension_low: cable 2" if i % 500 == 7 else ""
    d["tip_x_mm"] = math.nan if i % 11 == 0 else d["tip_x_mm"]
    return d


def _frame(i: int, t: float) -> can.Message:
    return can.Message(
        timestamp=t, arbitration_id=0x181 + i % 3, data=bytes([i % 256, 1, 2, 3]), is_rx=True
    )


def test_official_readers_read_every_message_of_a_logged_run(tmp_path):
    rng = np.random.default_rng(3)
    w = RunLogWriter(
        tmp_path / "run",
        COLS,
        RunMetadata(name="interop", rate_hz=RATE_HZ),
        config_text="name: interop\n",
        second_sink=McapSinkFactory(ModelTip(lambda psi: np.ones(3)), RATE_HZ),
        fsync_every_s=0.05,
    )
    events = 0
    for i in range(ROWS):
        row = _row(i, rng)
        events += bool(row["event"])
        w.write(row)
        for k in range(FRAMES_PER_ROW):
            w.can_tap.on_message_received(_frame(i * FRAMES_PER_ROW + k, 1.7e9 + i / RATE_HZ))
    w.close("done", outcome="completed")
    assert w.stats.complete
    n = len(load_run(tmp_path / "run"))  # samples.csv
    assert n == ROWS

    got = nodejs.read_mcap(tmp_path / "run" / RUN_MCAP)[str(tmp_path / "run" / RUN_MCAP)]
    every = streams.model_tip_every(RATE_HZ)
    want = {topic: n for topic in (*streams.PER_CYCLE, streams.EXTRA)}
    want |= {
        streams.TIP_MODEL: math.ceil(n / every),
        streams.EVENTS: events,
        streams.CAN: ROWS * FRAMES_PER_ROW,
    }
    idx, stream = got["indexed"], got["stream"]
    assert "error" not in idx, idx["error"]
    assert idx["chunks"] > 3  # many flushes: the indexes of every chunk are read
    assert idx["counts"] == want
    assert idx["statisticsCount"] == sum(want.values())
    assert idx["outOfOrder"] == 0  # the indexed reader yields in log-time order
    assert idx["channels"] == {t: name for t, (name, _) in streams.SCHEMAS.items()}
    assert {"config.yaml", "run.yaml"} <= set(idx["attachments"])
    assert idx["metadata"]["run"]["rate_hz"] == "1000.0"  # plain text, no YAML end marker
    assert not any(v.endswith("...") for md in idx["metadata"].values() for v in md.values())
    assert stream["counts"] == want and stream["footer"] and "error" not in stream
    for res in (idx, stream):  # every message JSON, with t_s and cycle, on every channel
        assert res["failures"] == {"json": 0, "missingHead": {}}


def test_a_file_cut_after_a_flush_reads_in_the_stream_reader_up_to_it(tmp_path):
    rng = np.random.default_rng(4)
    rows = [_row(i, rng) for i in range(300)]
    path = tmp_path / RUN_MCAP
    sink = McapSink(path, COLS)
    ends = []  # the file's size after each flush
    for part in (rows[:120], rows[120:]):
        sink.write_rows(part)
        sink.flush()
        ends.append(path.stat().st_size)
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(path.read_bytes()[: sum(ends) // 2])  # the writer killed mid-chunk
    sink.close()
    got = nodejs.read_mcap(cut, path)
    stream = got[str(cut)]["stream"]
    assert "error" not in stream and not stream["footer"] and stream["leftoverBytes"] > 0
    assert {t: stream["counts"].get(t) for t in streams.PER_CYCLE} == dict.fromkeys(
        streams.PER_CYCLE, 120
    )
    assert stream["failures"] == {"json": 0, "missingHead": {}}
    # The whole file, for comparison, in both readers.
    full = got[str(path)]
    assert full["indexed"]["counts"][streams.COMMAND] == full["stream"]["counts"][streams.COMMAND]
    assert full["indexed"]["counts"][streams.COMMAND] == 300
