"""The run-log writer process's scheduling policy follows what its ring does when full: a loop on
simulated time waits for it (``on_full="wait"``), so it runs at SCHED_IDLE, on CPU time nobody
else wants (the lock-step truth worker is on the critical path); a real-time loop never waits
(``"trip"``), and its writer stays at SCHED_BATCH, a fair share that never preempts the loop."""

from __future__ import annotations

import os
import time

import pytest

from cdcr_ctl.runlog.writer.spawn import start_writer_process, writer_policy


def test_policy_by_what_a_full_ring_does():
    assert writer_policy("wait") == "SCHED_IDLE"
    assert writer_policy("trip") == "SCHED_BATCH"


@pytest.mark.parametrize("on_full", ["wait", "trip"])
def test_the_started_process_runs_at_that_policy(on_full):
    proc = start_writer_process(on_full=on_full)
    try:
        want = getattr(os, writer_policy(on_full))
        # The policy is set by the process's first statements, before its imports.
        deadline = time.monotonic() + 10.0
        while os.sched_getscheduler(proc.pid) != want and time.monotonic() < deadline:
            time.sleep(0.01)
        assert os.sched_getscheduler(proc.pid) == want
    finally:
        proc.stdin.close()  # a spare without settings exits when its stdin closes
        proc.wait(10.0)
