"""The process writer's handoff (issue #23, the log stage's mean): in real time the loop's
``write`` only queues the row, and a thread stores the rows into the ring while the loop is
between cycles (``quiet``). Same files as storing on the loop's thread; nothing stored while the
loop is in a cycle; a close stores what is queued first; a full ring still refuses rows; a
SIGKILL of the loop's process loses at most the rows of the last feed period, inside the
issue's rule of ``fsync_every_s``."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import threading

import numpy as np
import pytest
import yaml
from test_runlog_process import COLS, _rows, _wait
from waits import wait_for

from cdcr_ctl.runlog import RunMetadata, load_run
from cdcr_ctl.runlog.writer import handoff
from cdcr_ctl.runlog.writer.process import ProcessRunLogWriter
from cdcr_ctl.runlog.writer.ring import ROW_HEAD

WAIT_S = 30.0  # generous: the machine may be loaded; nothing here measures time


class Gate:
    """A ``quiet`` predicate the test opens and closes (the loop between / in its cycles)."""

    def __init__(self, open_: bool) -> None:
        self.open = open_
        self.calls = 0

    def __call__(self) -> bool:
        self.calls += 1
        return self.open


def _writer(tmp_path, name, **kw) -> ProcessRunLogWriter:
    return ProcessRunLogWriter(tmp_path / name, COLS, RunMetadata(name=name, rate_hz=1000.0), **kw)


def test_handed_over_rows_make_the_same_file_as_rows_stored_in_write(tmp_path):
    rows = _rows(400)
    direct = _writer(tmp_path, "direct")
    handed = _writer(tmp_path, "handed", quiet=Gate(True))
    assert direct._handoff is None and handed._handoff is not None
    for w in (direct, handed):
        for r in rows:
            assert w.write(r)
        w.close("done", outcome="completed")
        assert w.failure is None and w.stats.complete, w.stats
    assert (handed.run_dir / "samples.csv").read_bytes() == (
        direct.run_dir / "samples.csv"
    ).read_bytes()
    ended = yaml.safe_load((handed.run_dir / "run.yaml").read_text())["ended"]
    assert ended["rows"] == {"queued": 400, "written": 400, "dropped": 0, "lost": 0}


def test_nothing_is_stored_while_the_loop_is_in_a_cycle(tmp_path):
    gate = Gate(False)
    w = _writer(tmp_path, "gated", quiet=gate)
    rows = _rows(50)
    assert all(w.write(r) for r in rows)
    # The handoff thread looks (it polls the gate) but stores nothing while it is shut.
    assert _wait(lambda: gate.calls >= 5)
    assert w._ring.hq[ROW_HEAD] == 0 and w._handoff.queued() == 50
    gate.open = True
    assert _wait(lambda: w._ring.hq[ROW_HEAD] == 50)
    assert w._handoff.queued() == 0
    w.close("done", outcome="completed")
    assert len(load_run(w.run_dir)) == 50


def test_past_the_backlog_rows_are_stored_whatever_quiet_says(tmp_path):
    """A loop that is never between cycles (late after late) does not keep its rows waiting
    without bound: at most half ``fsync_every_s`` of them (here 0.5 * 0.2 s at 1 kHz = 100)."""
    gate = Gate(False)
    w = _writer(tmp_path, "late", quiet=gate, fsync_every_s=0.2)
    assert all(w.write(r) for r in _rows(400))
    assert _wait(lambda: w._ring.hq[ROW_HEAD] >= 300)
    assert w._handoff.queued() <= 100 and w._ring.hq[ROW_HEAD] + w._handoff.queued() == 400
    gate.open = True
    w.close("done", outcome="completed")
    assert w.stats.written == 400 and len(load_run(w.run_dir)) == 400


def test_close_stores_the_queued_rows_before_the_close_request(tmp_path, monkeypatch):
    """Rows still queued when the run ends are written (the request follows them)."""
    monkeypatch.setattr(handoff, "FEED_PERIOD_S", 60.0)  # no periodic feed: only the close's
    w = _writer(tmp_path, "close", quiet=Gate(True))
    assert all(w.write(r) for r in _rows(120))
    assert w._ring.hq[ROW_HEAD] == 0
    w.close("done", outcome="completed")
    assert w.closed and w.stats.written == 120 and w.stats.lost == 0
    ended = yaml.safe_load((w.run_dir / "run.yaml").read_text())["ended"]
    assert ended["outcome"] == "completed" and ended["rows"]["written"] == 120


def test_a_full_ring_still_refuses_rows_and_names_the_overflow(tmp_path):
    """Rows handed over count against the ring as rows in it: with the writer process stopped,
    the ring's size in rows is accepted, then ``write`` refuses (the loop trips)."""
    w = _writer(tmp_path, "full", quiet=Gate(True), max_queued_rows=16)
    os.kill(w._proc.pid, signal.SIGSTOP)
    try:
        accepted = [w.write(r) for r in _rows(20)]
        assert accepted == [True] * 16 + [False] * 4
        assert w.overflow is not None and "16 rows" in w.overflow
    finally:
        os.kill(w._proc.pid, signal.SIGCONT)
    w.close("done", outcome="tripped")
    assert w.stats.queued == 16 and w.stats.written == 16 and w.stats.lost == 0


def test_a_loop_on_simulated_time_stores_in_write(tmp_path):
    """``on_full="wait"`` (lock-step): no handoff, whatever ``quiet`` says."""
    w = _writer(tmp_path, "wait", quiet=Gate(False), on_full="wait")
    assert w._handoff is None
    assert w.write(_rows(1)[0]) and w._ring.hq[ROW_HEAD] == 1
    w.close("done")


@pytest.mark.skipif(not hasattr(os, "SCHED_BATCH"), reason="Linux scheduling policies")
def test_the_handoff_thread_takes_the_loop_threads_scheduling(tmp_path):
    """A thread holding the interpreter lock must not be preempted by work the loop is not: the
    handoff thread takes the policy of the thread that hands the first row over (SCHED_BATCH
    here: any thread may take it, no privilege needed)."""
    w = _writer(tmp_path, "sched", quiet=Gate(True))
    rows = _rows(3)

    def loop() -> None:
        os.sched_setscheduler(0, os.SCHED_BATCH, os.sched_param(0))
        for r in rows:
            w.write(r)

    t = threading.Thread(target=loop)
    t.start()
    t.join()
    tid = w._handoff._thread.native_id
    assert wait_for(lambda: os.sched_getscheduler(tid) == os.SCHED_BATCH, WAIT_S, 0.01)
    w.close("done")


CHILD = textwrap.dedent(
    """
    import os, signal, sys, time
    from cdcr_ctl.runlog import RunMetadata, sample_columns
    from cdcr_ctl.runlog.writer.process import ProcessRunLogWriter
    rate = 1000.0
    w = ProcessRunLogWriter(sys.argv[1], sample_columns(1, 3), RunMetadata(name="killed"),
                            fsync_every_s=0.5, quiet=lambda: True)
    n = int(sys.argv[2])
    t0 = time.monotonic()
    for i in range(n):  # at the loop's rate, on the wall clock
        while time.monotonic() < t0 + i / rate:
            time.sleep(0.0002)
        w.write({"t_s": i / rate, "cable1_q_cmd_mm": float(i)})
    os.kill(os.getpid(), signal.SIGKILL)
    """
)


def test_sigkill_of_the_loop_process_loses_at_most_fsync_every_s_of_rows(tmp_path):
    """The issue's rule (acceptance 2): no more than ``fsync_every_s`` of samples missing. The
    rows the handoff had not stored yet are lost with the process (at most the last feed
    period's); every row in the ring is written, in order, and the run closed."""
    run_dir = tmp_path / "r"
    n = 1500
    proc = subprocess.run(
        [sys.executable, "-c", CHILD, str(run_dir), str(n)], capture_output=True, text=True
    )
    assert proc.returncode == -signal.SIGKILL, proc.stderr
    run_yaml = run_dir / "run.yaml"
    assert _wait(
        lambda: run_yaml.is_file() and (yaml.safe_load(run_yaml.read_text()) or {}).get("ended")
    )
    ended = yaml.safe_load(run_yaml.read_text())["ended"]
    assert ended["outcome"] == "aborted"
    run = load_run(run_dir)
    q = run.column("cable1_q_cmd_mm")  # the row numbers (whole numbers: exact in float64)
    assert np.array_equal(q, np.arange(len(q)))  # a prefix of the rows, in order
    assert ended["rows"]["written"] == len(q)
    assert (n - len(q)) / 1000.0 <= 0.5  # fsync_every_s (0.5 s) of samples at most
