"""The loop and a full run-log ring (issue #23): in real time the loop never waits for the writer;
a full ring trips ``log_overflow`` (quick stop, the log kept, the cause named). On simulated time
(lock-step) a full ring makes the loop wait, so no row is lost and the log is the same whatever
the writer's speed.

The writer falls behind on purpose: its process is stopped (SIGSTOP) while the loop runs, so
nothing here depends on the machine's speed.
"""

from __future__ import annotations

import os
import signal

import pytest
import yaml
from test_loop import Ramp, clocked_loop, make_loop, wait_until

from cdcr_ctl.control.loop import ControlLoop
from cdcr_ctl.control.supervisor import Reaction
from cdcr_ctl.runlog import LOOP_EXTRA_COLUMNS, RunMetadata, load_run, sample_columns
from cdcr_ctl.runlog.writer.process import ProcessRunLogWriter
from cdcr_ctl.sim.lockstep.clock import SimClock

COLS = sample_columns(1, 3, LOOP_EXTRA_COLUMNS)
RING = 16  # rows: filled within a few cycles once the writer is stopped
WAIT_S = 30.0  # generous: the machine may be loaded; nothing here measures time


def _writer(tmp_path, name: str, on_full: str, rows: int = RING) -> ProcessRunLogWriter:
    return ProcessRunLogWriter(
        tmp_path / name,
        COLS,
        RunMetadata(name=name, rate_hz=500.0),
        max_queued_rows=rows,
        on_full=on_full,
    )


def test_a_full_ring_in_real_time_trips_log_overflow_and_keeps_the_log(tmp_path):
    loop, drives, _ten, sup = make_loop()
    w = _writer(tmp_path, "rt", "trip")
    os.kill(w._proc.pid, signal.SIGSTOP)  # the writer falls behind
    try:
        loop.start()
        run = loop.follow(Ramp(0.3, 5.0), "ramp", "model", w)
        assert wait_until(lambda: run.state != "running", WAIT_S)
        # The loop went on cycling (never blocked on the writer) and tripped.
        assert run.state == "tripped" and run.end_reason.startswith("log_overflow: ")
        assert sup.trip.cause == "log_overflow" and sup.trip.reaction is Reaction.QUICK_STOP
        assert drives.quick_stops == 1
        assert str(w.samples_path) in sup.trip.detail and f"{RING} rows" in sup.trip.detail
        assert run.rows == RING and loop.counters.rows_dropped >= 1
    finally:
        os.kill(w._proc.pid, signal.SIGCONT)
        loop.stop()
    assert w.wait_closed(WAIT_S)
    ended = yaml.safe_load((w.run_dir / "run.yaml").read_text())["ended"]
    assert ended["outcome"] == "tripped" and ended["reason"].startswith("log_overflow: ")
    assert ended["rows"]["written"] == RING and ended["rows"]["dropped"] >= 1
    assert len(load_run(w.run_dir)) == RING  # every row the ring took is on disk


def _lockstep_loop() -> tuple[ControlLoop, SimClock]:
    clock = SimClock(0.002, advance=lambda t0, t1: None)
    loop = clocked_loop(clock)
    return loop, clock


def _lockstep_run(w: ProcessRunLogWriter, stall: bool):
    loop, _clock = _lockstep_loop()
    loop.start()
    try:
        if stall:
            os.kill(w._proc.pid, signal.SIGSTOP)
        try:
            run = loop.follow(Ramp(0.3, 0.5), "ramp", "model", w)
            if stall:
                # The loop waits in the log stage with the ring full: no row refused, the run
                # held in simulated time until the writer makes room.
                assert wait_until(lambda: w.waits >= 1, WAIT_S)
                assert run.state == "running" and run.rows == RING
                assert loop.counters.rows_dropped == 0
        finally:
            if stall:
                os.kill(w._proc.pid, signal.SIGCONT)
        assert wait_until(lambda: run.state != "running", WAIT_S)
    finally:
        loop.stop()
    assert w.wait_closed(WAIT_S)
    return run, loop


def test_a_full_ring_on_simulated_time_makes_the_loop_wait_and_loses_nothing(tmp_path):
    stalled = _writer(tmp_path, "stalled", "wait")
    run, loop = _lockstep_run(stalled, stall=True)
    assert run.state == "completed" and loop.supervisor.trip is None
    assert loop.counters.rows_dropped == 0 and run.rows > 10 * RING
    ended = yaml.safe_load((stalled.run_dir / "run.yaml").read_text())["ended"]
    assert ended["rows"] == {"queued": run.rows, "written": run.rows, "dropped": 0, "lost": 0}
    # The same run with a ring that never fills: the same file, byte for byte.
    roomy = _writer(tmp_path, "roomy", "wait", rows=100_000)
    run2, _ = _lockstep_run(roomy, stall=False)
    assert roomy.waits == 0 and run2.rows == run.rows
    a = (stalled.run_dir / "samples.csv").read_bytes()
    assert a == (roomy.run_dir / "samples.csv").read_bytes()


def test_on_full_is_checked():
    with pytest.raises(ValueError, match="on_full"):
        ProcessRunLogWriter("/nonexistent/x", COLS, RunMetadata(name="x"), on_full="block")
