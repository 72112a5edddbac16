"""Waiting for a run through the daemon: given up on when it stops progressing.

Used by the commands that run trajectories and wait for each (``demo``, ``identify``,
``experiments``).
"""

from __future__ import annotations

import time
from typing import Any

#: A run is given up on after this long without progress (s of wall time).
RUN_SLACK_S = 60.0


def run_deadline(
    st: dict[str, Any], run_id: str, end: float, elapsed: float
) -> tuple[float, float]:
    """(deadline, elapsed) after one ``status`` answer ``st`` while waiting for run
    ``run_id``: the deadline moves to :data:`RUN_SLACK_S` from now whenever the run's elapsed
    time (the loop's clock: simulated time on a lock-step rig) has grown since the last answer.
    A lock-step rig on a loaded machine runs slower than the wall clock, so a run is given up
    on when it stops progressing, not when the wall clock passes its duration."""
    run = st.get("run") or {}
    if run.get("id") == run_id:
        now_elapsed = float(run.get("elapsed_s", 0.0))
        if now_elapsed > elapsed:
            return max(end, time.monotonic() + RUN_SLACK_S), now_elapsed
    return end, elapsed
