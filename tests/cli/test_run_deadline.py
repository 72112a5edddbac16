"""cdcr_ctl.cli.runwait.run_deadline: a run is waited for while it progresses (a lock-step
rig on a loaded machine runs slower than the wall clock), and given up on when it stops."""

from __future__ import annotations

import time

from cdcr_ctl.cli.runwait import RUN_SLACK_S, run_deadline


def _status(run_id: str, elapsed_s: float) -> dict:
    return {"run": {"id": run_id, "elapsed_s": elapsed_s}, "runs": []}


def test_progress_moves_the_deadline_and_a_stall_does_not():
    end = time.monotonic() + 1.0  # the run's duration + slack has all but passed
    end, seen = run_deadline(_status("r1", 0.5), "r1", end, -1.0)
    assert end >= time.monotonic() + RUN_SLACK_S - 1.0 and seen == 0.5
    stalled_end, seen2 = run_deadline(_status("r1", 0.5), "r1", end, seen)
    assert (stalled_end, seen2) == (end, 0.5)  # no progress: the deadline stays


def test_another_run_or_none_leaves_the_deadline():
    end = time.monotonic() + 1.0
    assert run_deadline(_status("other", 9.0), "r1", end, -1.0) == (end, -1.0)
    assert run_deadline({"run": None, "runs": []}, "r1", end, 2.0) == (end, 2.0)
