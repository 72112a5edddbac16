"""The run-log writer process's priority follows what its ring does when full: a loop on
simulated time waits for it (``on_full="wait"``), so once it has its run it stays at nice 10 (the
lock-step truth worker, on the critical path, preempts it; beside a CPU-bound neighbour it still
gets a tenth of a nice-0 share); a real-time loop never waits (``"trip"``), and its writer runs at
the daemon's own nice. Both are SCHED_BATCH (a drain never preempts a running task)."""

from __future__ import annotations

import os
import time

import pytest

from cdcr_ctl.runlog.writer.spawn import (
    SPARE_NICE,
    WAITING_WRITER_NICE,
    WRITER_NICE,
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
