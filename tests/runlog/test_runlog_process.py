"""The writer process (``logging.writer: process``): the same files as the writer thread, its
errors reach the loop's side, a full ring refuses rows, and a SIGKILL of either process leaves
readable logs (issue #23, acceptance 5: the encoding leaves the loop's process)."""

from __future__ import annotations

import itertools
import json
import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import can
import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st
from mcap.reader import make_reader
from waits import wait_for

from cdcr_ctl.control.loop.rows import CycleRow, RowLayout
from cdcr_ctl.runlog import LOOP_EXTRA_COLUMNS, RunLogWriter, RunMetadata, load_run, sample_columns
from cdcr_ctl.runlog.mcap_sink import RUN_MCAP, McapSinkFactory
from cdcr_ctl.runlog.writer.process import ProcessRunLogWriter
from cdcr_ctl.runlog.writer.ring import CUT_MARK, EVENT_BYTES, RingLayout, SharedRing

S, K = 2, 3
COLS = sample_columns(S, K, LOOP_EXTRA_COLUMNS)
WAIT_S = 30.0  # generous: the machine may be loaded; nothing here measures time


def _wait(pred, timeout_s: float = WAIT_S) -> bool:
    return wait_for(pred, timeout_s, 0.01)


def _rows(n: int) -> list:
    """Loop rows (CycleRow, as the loop hands them over) and plain mappings, NaNs and events."""
    layout = RowLayout(S, K)
    rng = np.random.default_rng(7)
    out: list = []
    for i in range(n):
        values = rng.normal(size=2 * S + 4 * K + 3) * 10.0 ** rng.integers(-6, 4)
        if i % 7 == 3:
            values[-3:] = np.nan  # tracker sample missing
        event = 'trip: x, "quoted"\nnewline' if i % 50 == 10 else ""
        if i % 10 == 9:
            d = CycleRow(layout, i * 1e-3, i, values, 3.3e-6 * i, event).columns()
            out.append(dict(d))  # a plain mapping, as other writers of rows hand them over
        else:
            out.append(CycleRow(layout, i * 1e-3, i, values, 3.3e-6 * i, event))
    return out


def _frames(n: int) -> list[can.Message]:
    return [
        can.Message(timestamp=1000.0 + i * 1e-3, arbitration_id=0x181 + i % 3,
                    data=bytes([i % 256, 2, 3]), is_extended_id=False, is_rx=bool(i % 2))
        for i in range(n)
    ]  # fmt: skip


def _write_both(tmp_path: Path, rows: list, frames: list) -> tuple[Path, Path]:
    dirs = []
    for cls in (RunLogWriter, ProcessRunLogWriter):
        w = cls(
            tmp_path / cls.__name__,
            COLS,
            RunMetadata(name="same", rate_hz=1000.0),
            second_sink=McapSinkFactory(None, 1000.0),
        )
        for r in rows:
            assert w.write(r)
        for f in frames:
            w.can_tap.on_message_received(f)
        w.close("done", outcome="completed")
        assert w.failure is None and w.stats.complete, w.stats
        dirs.append(w.run_dir)
    return dirs[0], dirs[1]


def _messages(path: Path) -> dict[str, list[bytes]]:
    out: dict[str, list[bytes]] = {}
    with open(path, "rb") as f:
        for _, channel, message in make_reader(f).iter_messages(log_time_order=False):
            out.setdefault(channel.topic, []).append(message.data)
    return out


def test_the_process_writes_what_the_thread_writes(tmp_path):
    """Float64 numbers are copied through the ring unchanged (no arithmetic), so the CSV text
    (exact ``repr``) and the MCAP messages are identical to the thread writer's, byte for byte."""
    rows, frames = _rows(600), _frames(90)
    thread_dir, proc_dir = _write_both(tmp_path, rows, frames)
    assert (proc_dir / "samples.csv").read_bytes() == (thread_dir / "samples.csv").read_bytes()
    a, b = _messages(thread_dir / RUN_MCAP), _messages(proc_dir / RUN_MCAP)
    assert a.keys() == b.keys() and "/can" in a and "/events" in a
    assert len(a["/command"]) == len(rows) and len(a["/can"]) == len(frames)
    for topic in a:
        if topic == "/can":  # the frames, in order; t_s and cycle are those of the last row
            # written before each, which depends on how each writer batched rows and frames
            def frame(m: bytes) -> dict:
                return {k: v for k, v in json.loads(m).items() if k not in ("t_s", "cycle")}

            assert [frame(m) for m in a[topic]] == [frame(m) for m in b[topic]]
        else:
            assert a[topic] == b[topic], topic
    ended = yaml.safe_load((proc_dir / "run.yaml").read_text())["ended"]
    assert ended["outcome"] == "completed"
    assert ended["rows"] == {"queued": 600, "written": 600, "dropped": 0, "lost": 0}


def test_a_long_event_is_cut_and_marked(tmp_path):
    w = ProcessRunLogWriter(tmp_path / "r", COLS, RunMetadata(name="cut"))
    assert w.write({"t_s": 0.0, "event": "é" * EVENT_BYTES})
    w.close("done")
    run = load_run(tmp_path / "r")
    event = run.column("event")[0]
    assert event.endswith(CUT_MARK) and len(event.encode()) <= EVENT_BYTES
    assert set(event.removesuffix(CUT_MARK)) == {"é"}


def test_a_full_ring_refuses_rows_and_run_yaml_counts_them(tmp_path):
    w = ProcessRunLogWriter(tmp_path / "r", ["t_s"], RunMetadata(name="full"), max_queued_rows=20)
    os.kill(w._proc.pid, signal.SIGSTOP)  # the writer process falls behind
    try:
        accepted = [w.write({"t_s": i * 1e-3}) for i in range(25)]
    finally:
        os.kill(w._proc.pid, signal.SIGCONT)
    assert accepted == [True] * 20 + [False] * 5
    assert str(w.samples_path) in w.overflow and "ring full (20 rows" in w.overflow
    w.close("done")
    assert w.stats.queued == 20 and w.stats.written == 20 and w.stats.dropped == 5
    ended = yaml.safe_load((tmp_path / "r" / "run.yaml").read_text())["ended"]
    assert ended["rows"]["dropped"] == 5 and ended["rows"]["written"] == 20


@pytest.mark.parametrize("quiet", [None, lambda: True], ids=["stored-in-write", "handoff"])
def test_a_vanished_run_directory_reaches_the_loop_side(tmp_path, quiet):
    """With a handoff (``quiet``) the loop's ``failure`` reads no shared flag: the handoff
    thread does, every feed, and the loop sees the failure (and the callback runs) as without."""
    failures: list[str] = []
    w = ProcessRunLogWriter(
        tmp_path / "r", COLS, RunMetadata(name="gone"), fsync_every_s=0.1,
        on_failure=failures.append, drain_interval_s=0.01, quiet=quiet,
    )  # fmt: skip
    rows = itertools.cycle(_rows(500))
    assert _wait(lambda: w.write(next(rows)) and w.stats.fsyncs >= 2)
    for p in sorted(w.run_dir.iterdir()):
        p.unlink()
    w.run_dir.rmdir()
    assert _wait(lambda: (w.write(next(rows)) or True) and w.failure is not None)
    assert "deleted" in w.failure or "gone" in w.failure, w.failure
    assert failures == [w.failure]
    assert w.write(next(rows)) is False
    w.close("after the failure")
    assert w.closed


CHILD = textwrap.dedent(
    """
    import os, signal, sys, time
    import numpy as np
    from cdcr_ctl.runlog import RunMetadata, sample_columns
    from cdcr_ctl.runlog.mcap_sink import McapSinkFactory
    from cdcr_ctl.runlog.writer.process import ProcessRunLogWriter
    w = ProcessRunLogWriter(sys.argv[1], sample_columns(1, 3), RunMetadata(name="killed"),
                            fsync_every_s=60.0, second_sink=McapSinkFactory(None, 1000.0))
    for i in range(int(sys.argv[2])):
        w.write({"t_s": i * 1e-3, "cable1_q_cmd_mm": float(i)})
    print(w._proc.pid, flush=True)
    os.kill(os.getpid(), signal.SIGKILL)
    """
)


def test_sigkill_of_the_loop_process_the_writer_drains_and_closes_the_run(tmp_path):
    """The loop's process dies with rows still in the ring and no fsync for 60 s: the writer
    process sees its parent go, writes every row and closes both files whole."""
    run_dir = tmp_path / "r"
    proc = subprocess.run(
        [sys.executable, "-c", CHILD, str(run_dir), "3000"], capture_output=True, text=True
    )
    assert proc.returncode == -signal.SIGKILL, proc.stderr
    run_yaml = run_dir / "run.yaml"
    assert _wait(
        lambda: run_yaml.is_file() and (yaml.safe_load(run_yaml.read_text()) or {}).get("ended")
    )
    ended = yaml.safe_load(run_yaml.read_text())["ended"]
    assert ended["outcome"] == "aborted" and "daemon process ended" in ended["reason"]
    assert ended["rows"]["written"] == 3000 and ended["rows"]["lost"] == 0
    csv_run, mcap_run = load_run(run_dir), load_run(run_dir / RUN_MCAP)
    assert len(csv_run) == len(mcap_run) == 3000 and not mcap_run.warnings
    with open(run_dir / RUN_MCAP, "rb") as f:
        summary = make_reader(f).get_summary()  # a complete file: summary and footer
    assert summary is not None and summary.statistics.message_count >= 5 * 3000


def test_sigkill_of_the_writer_process_fails_the_log_and_keeps_the_last_flush(tmp_path):
    failures: list[str] = []
    w = ProcessRunLogWriter(
        tmp_path / "r", COLS, RunMetadata(name="writer-killed"), fsync_every_s=0.1,
        on_failure=failures.append, second_sink=McapSinkFactory(None, 1000.0),
    )  # fmt: skip
    rows = itertools.cycle(_rows(500))
    assert _wait(lambda: w.write(next(rows)) and w.stats.fsyncs >= 3)
    os.kill(w._proc.pid, signal.SIGKILL)
    assert _wait(lambda: (w.write(next(rows)) or True) and w.failure is not None)
    assert "writer process ended" in w.failure and failures == [w.failure]
    w.close("after the kill")
    run = load_run(tmp_path / "r" / RUN_MCAP)  # up to its last flush
    assert len(run) > 0 and run.warnings and "last flush" in run.warnings[0]


def test_a_start_error_names_the_run_directory(tmp_path):
    (tmp_path / "r").mkdir()
    (tmp_path / "r" / "stray").write_text("x")
    with pytest.raises(Exception, match="not empty") as info:
        ProcessRunLogWriter(tmp_path / "r", COLS, RunMetadata(name="x"))
    assert str(tmp_path / "r") in str(info.value)


def can_frames(max_size: int) -> st.SearchStrategy:
    """Lists of (timestamp s, COB-ID, flags, DLC, data) as the ring stores a CAN frame."""
    return st.lists(
        st.tuples(
            st.floats(0, 1e10, allow_nan=False),
            st.integers(0, 2**29 - 1),
            st.integers(0, 15),
            st.integers(0, 15),
            st.binary(max_size=64),
        ),
        max_size=max_size,
    )


@settings(max_examples=60, deadline=None)
@given(frames=can_frames(12))
def test_can_records_round_trip_through_the_ring(frames):
    ring = SharedRing.create(RingLayout(n_numbers=1, rows=1, frames=8))
    try:
        got = []
        for chunk in (frames[:8], frames[8:]):
            for ts, cob, flags, dlc, data in chunk:
                assert ring.put_frame(ts, cob, flags, dlc, data)
            got += ring.take_frames()
        want = [
            (ts, cob, bool(f & 1), bool(f & 2), bool(f & 4), bool(f & 8), dlc, data)
            for ts, cob, f, dlc, data in frames
        ]
        assert got == want
        for _ in range(8):
            ring.put_frame(0.0, 1, 0, 0, b"")
        assert not ring.put_frame(0.0, 1, 0, 0, b"")  # full: refused, nothing overwritten
    finally:
        ring.close()


@settings(max_examples=60, deadline=None)
@given(
    frames=can_frames(30),
    batch=st.integers(1, 9),
    taken_every=st.integers(1, 4),
)
def test_a_batch_of_frames_is_stored_as_frame_by_frame_byte_for_byte(frames, batch, taken_every):
    # The loop's process hands the traffic log's frames over a batch at a time (one numpy store,
    # two where the ring wraps); the ring's bytes and what the writer takes are the same as one
    # ``struct`` store per frame, and a batch larger than the room left stores its first frames.
    per_frame = SharedRing.create(RingLayout(n_numbers=1, rows=1, frames=8))
    batched = SharedRing.create(RingLayout(n_numbers=1, rows=1, frames=8))
    try:
        got_a, got_b = [], []
        chunks = [frames[i : i + batch] for i in range(0, len(frames), batch)]
        for n, chunk in enumerate(chunks):
            records = [(ts, cob, f, dlc, len(data), data) for ts, cob, f, dlc, data in chunk]
            stored_a = 0
            for ts, cob, f, dlc, data in chunk:
                stored_a += per_frame.put_frame(ts, cob, f, dlc, data)
            assert batched.put_frames(records) == stored_a
            assert bytes(per_frame.can) == bytes(batched.can)
            if n % taken_every == 0:
                got_a += per_frame.take_frames()
                got_b += batched.take_frames()
        assert got_a == got_b
    finally:
        per_frame.close()
        batched.close()


class _Values:
    """A row handing over its numbers as another dtype than float64 (numpy converts them)."""

    def __init__(self, layout: RowLayout, i: int) -> None:
        self.row = CycleRow(layout, i * 1e-3, i, np.arange(2 * S + 4 * K + 3) * i, 1e-6 * i, "")

    def row_parts(self):
        keys, values, *rest = self.row.row_parts()
        return (keys, values.astype(np.int32), *rest)


def test_a_row_of_other_numbers_than_float64_is_logged_as_floats(tmp_path):
    layout = RowLayout(S, K)
    w = ProcessRunLogWriter(tmp_path / "r", COLS, RunMetadata(name="ints"))
    assert all(w.write(_Values(layout, i)) for i in range(5))
    w.close("done")
    run = load_run(tmp_path / "r")
    assert run.column("cable1_q_cmd_mm").tolist() == [float((2 * S + K) * i) for i in range(5)]
