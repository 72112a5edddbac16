"""The run-log writer process's priority follows what its ring does when full: a loop on
simulated time waits for it (``on_full="wait"``), so once it has its run it stays at nice 10 (the
lock-step truth worker, on the critical path, preempts it; beside a CPU-bound neighbour it still
gets a tenth of a nice-0 share); a real-time loop never waits (``"trip"``), and its writer runs at
the daemon's own nice. Both are SCHED_BATCH (a drain never preempts a running task)."""

from __future__ import annotations

import os
import threading
import time

import pytest

from cdcr_ctl.runlog.writer.files import RunMetadata
from cdcr_ctl.runlog.writer.process import ProcessRunLogWriter
from cdcr_ctl.runlog.writer.spawn import (
    SPARE_NICE,
    WAITING_WRITER_NICE,
    WRITER_NICE,
    WRITER_RT_PRIORITY,
    start_writer_process,
    writer_nice,
)

#: The largest nice level Linux gives (setpriority(2)).
MAX_NICE = 19


def test_run_nice_by_what_a_full_ring_does():
    assert writer_nice("wait") == WAITING_WRITER_NICE == 10
    assert writer_nice("trip") == WRITER_NICE == 0


@pytest.mark.parametrize("on_full", ["wait", "trip"])
def test_the_started_process_is_batch_and_carries_its_run_nice(on_full):
    base = os.getpriority(os.PRIO_PROCESS, 0)
    # The kernel clamps a nice level to 19 (scripts/test runs the rest of the suite at +10).
    spare = min(base + SPARE_NICE, MAX_NICE)
    proc = start_writer_process(on_full=on_full)
    try:
        # Its first statements: SCHED_BATCH and the spare's nice, before its imports.
        deadline = time.monotonic() + 30.0
        while (
            os.sched_getscheduler(proc.pid) != os.SCHED_BATCH
            or os.getpriority(os.PRIO_PROCESS, proc.pid) != spare
        ) and time.monotonic() < deadline:
            time.sleep(0.01)
        assert os.sched_getscheduler(proc.pid) == os.SCHED_BATCH
        assert os.getpriority(os.PRIO_PROCESS, proc.pid) == spare
        # The nice it takes with its run (child.main's run_nice), from its start-up code.
        assert f"main(run_nice=base + {writer_nice(on_full)})" in proc.args[-1]
    finally:
        proc.stdin.close()  # a spare without settings exits when its stdin closes
        proc.wait(60.0)


def _in_fifo_thread(fn):
    """``fn()`` on a thread at SCHED_FIFO 10 (a real-time loop's process); its result."""
    out: dict = {}

    def run() -> None:
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(10))  # this thread only
        except PermissionError:
            out["skip"] = True
            return
        out["value"] = fn()

    th = threading.Thread(target=run)
    th.start()
    th.join()
    if out.get("skip"):
        pytest.skip("needs the right to set SCHED_FIFO (root or CAP_SYS_NICE)")
    return out["value"]


def test_a_real_time_loop_hands_its_run_to_a_writer_at_the_lowest_real_time_priority(tmp_path):
    # Beside a SCHED_FIFO loop, a writer off real time can be starved by any ordinary work
    # (spawn.WRITER_RT_PRIORITY); at SCHED_FIFO 1 the loop's tasks still preempt it. Writers
    # started with their run (no spare), so the hand-over may come before their boot line.
    meta = RunMetadata(name="rt", rate_hz=100.0)
    cols = ["t_s", "cycle", "x"]
    writers = {
        "trip": _in_fifo_thread(lambda: ProcessRunLogWriter(tmp_path / "a", cols, meta)),
        "wait": _in_fifo_thread(
            lambda: ProcessRunLogWriter(tmp_path / "b", cols, meta, on_full="wait")
        ),
        "ordinary": ProcessRunLogWriter(tmp_path / "c", cols, meta),
    }
    try:
        assert writers["trip"].writer_policy == f"SCHED_FIFO {WRITER_RT_PRIORITY}"
        assert WRITER_RT_PRIORITY == 1
        # A lock-step ring (its loop waits for the writer) and an ordinary caller: off real time.
        assert writers["wait"].writer_policy is None and writers["ordinary"].writer_policy is None
        w = writers["trip"]
        w.write({"t_s": 0.0, "cycle": 0, "x": 1.0})
        deadline = time.monotonic() + 30.0
        while w.stats.written < 1 and time.monotonic() < deadline:
            time.sleep(0.01)  # the run under way in the writer process (its threads started)
        assert w.stats.written == 1
        pid = writers["trip"]._proc.pid
        # Its main thread and the threads it started for the run: SCHED_FIFO 1.
        for task in os.listdir(f"/proc/{pid}/task"):
            assert os.sched_getscheduler(int(task)) == os.SCHED_FIFO, task
            assert os.sched_getparam(int(task)).sched_priority == WRITER_RT_PRIORITY
        for name in ("wait", "ordinary"):
            assert os.sched_getscheduler(writers[name]._proc.pid) == os.SCHED_BATCH
    finally:
        for w in writers.values():
            w.close("test done")
